"""Mini-batch plans: which images, flipped or not, and which RoIs (docs/conventions.md "Training").

Every choice is a pure function of ``(seed, iteration, rank)``: no random state is carried from
one iteration to the next, so a resumed run (or a worker process) recomputes exactly the batches
an uninterrupted run would have drawn, without saving any numpy RNG state.

Images: the global slot ``p = (iteration * world_size + rank) * images_per_batch + k`` walks
through one seeded permutation of the training images per epoch, so each epoch sees every image
once and, within an iteration, distinct ranks get distinct images.
RoIs (Fast R-CNN): ``round(fg_fraction * rois_per_image)`` foreground RoIs at most, drawn
without replacement, and background RoIs for the rest (fewer when the image has fewer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_IMAGE_STREAM = 0  # separate seed streams for image order and per-slot choices
_SLOT_STREAM = 1


@dataclass(frozen=True)
class ImagePlan:
    """One image of a mini-batch: its roidb index, the flip, and the sampled RoI indices (fg first)."""

    image: int
    flip: bool
    rois: np.ndarray  # (n,) int64 indices into the record's RoIs
    num_fg: int


def image_order(seed: int, epoch: int, num_images: int) -> np.ndarray:
    """The permutation of the training images for one epoch."""
    return np.random.default_rng([seed, _IMAGE_STREAM, epoch]).permutation(num_images)


def slot_images(
    seed: int, iteration: int, num_images: int, images_per_batch: int, rank: int = 0, world_size: int = 1
) -> list[tuple[int, int]]:
    """(global slot, image index) of each image this rank trains on at ``iteration``."""
    if num_images <= 0:
        raise ValueError("no training images with RoIs")
    first = (iteration * world_size + rank) * images_per_batch
    out = []
    for slot in range(first, first + images_per_batch):
        epoch, position = divmod(slot, num_images)
        out.append((slot, int(image_order(seed, epoch, num_images)[position])))
    return out


def sample_rois(
    labels: np.ndarray, rng: np.random.Generator, rois_per_image: int, fg_fraction: float
) -> tuple[np.ndarray, int]:
    """Indices of the sampled RoIs (foreground first) and the foreground count.

    ``labels``: (R,) int, > 0 foreground class (1..19), 0 background.
    """
    fg = np.flatnonzero(labels > 0)
    bg = np.flatnonzero(labels == 0)
    num_fg = min(round(fg_fraction * rois_per_image), len(fg))
    num_bg = min(rois_per_image - num_fg, len(bg))
    fg = rng.choice(fg, num_fg, replace=False) if num_fg else fg[:0]
    bg = rng.choice(bg, num_bg, replace=False) if num_bg else bg[:0]
    return np.concatenate([fg, bg]).astype(np.int64), num_fg


def plan_batch(
    labels_per_image: list[np.ndarray],
    *,
    seed: int,
    iteration: int,
    images_per_batch: int,
    rois_per_image: int,
    fg_fraction: float,
    flip: bool,
    rank: int = 0,
    world_size: int = 1,
) -> list[ImagePlan]:
    """This rank's mini-batch at ``iteration``: images, flips and RoIs, reproducibly."""
    plans = []
    for slot, image in slot_images(
        seed, iteration, len(labels_per_image), images_per_batch, rank, world_size
    ):
        rng = np.random.default_rng([seed, _SLOT_STREAM, slot])
        flipped = bool(flip and rng.random() < 0.5)
        rois, num_fg = sample_rois(labels_per_image[image], rng, rois_per_image, fg_fraction)
        plans.append(ImagePlan(image, flipped, rois, num_fg))
    return plans
