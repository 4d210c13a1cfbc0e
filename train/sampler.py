"""Mini-batch plans: which images, flipped or not, and which RoIs (docs/conventions.md "Training").

Every choice is a pure function of ``(seed, iteration, rank)``: no random state is carried from
one iteration to the next, so a resumed run (or a worker process) recomputes exactly the batches
an uninterrupted run would have drawn, without saving any numpy RNG state.

Images: the global slot ``p = (iteration * world_size + rank) * images_per_batch + k`` walks
through one seeded permutation of the training images per epoch, so each epoch sees every image
once and, within an iteration, distinct ranks get distinct images. With shape groups (frames of
one size, ``data.group_by_shape``) the permutation is one of whole batches instead, each of one
group where the group fills it: a batch is padded to its largest image, and a 360-row frame
padded to 480 rows costs the step what the missing rows would. The images left over from the
groups' last batches fill mixed batches; the few that fill no batch wait for a later epoch.
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


def image_order(
    seed: int, epoch: int, num_images: int, groups: np.ndarray | None = None, images_per_batch: int = 1
) -> np.ndarray:
    """The training images of one epoch, in order: a permutation of all of them, or with
    ``groups`` ((num_images,) int, one shape group per image) whole batches in a seeded order,
    ``epoch_length`` images."""
    rng = np.random.default_rng([seed, _IMAGE_STREAM, epoch])
    if groups is None or num_images < images_per_batch:
        return rng.permutation(num_images)
    members = [rng.permutation(np.flatnonzero(groups == g)) for g in np.unique(groups)]
    left_over = [m[len(m) // images_per_batch * images_per_batch :] for m in members]
    batches = [
        b
        for m in [*members, rng.permutation(np.concatenate(left_over))]
        for b in _whole_batches(m, images_per_batch)
    ]
    return np.concatenate([batches[i] for i in rng.permutation(len(batches))])


def _whole_batches(images: np.ndarray, images_per_batch: int) -> list[np.ndarray]:
    """``images`` cut into batches of ``images_per_batch``; a last partial batch is dropped."""
    full = len(images) // images_per_batch * images_per_batch
    return [images[i : i + images_per_batch] for i in range(0, full, images_per_batch)]


def epoch_length(num_images: int, images_per_batch: int, grouped: bool) -> int:
    """Images per epoch: all, or with shape groups the whole batches (a multiple of the batch,
    so every epoch's batches start where a rank's batch does)."""
    if not grouped or num_images < images_per_batch:
        return num_images
    return num_images // images_per_batch * images_per_batch


def slot_images(
    seed: int,
    iteration: int,
    num_images: int,
    images_per_batch: int,
    rank: int = 0,
    world_size: int = 1,
    groups: np.ndarray | None = None,
) -> list[tuple[int, int]]:
    """(global slot, image index) of each image this rank trains on at ``iteration``."""
    if num_images <= 0:
        raise ValueError("no training images with RoIs")
    length = epoch_length(num_images, images_per_batch, groups is not None)
    first = (iteration * world_size + rank) * images_per_batch
    orders: dict[int, np.ndarray] = {}
    out = []
    for slot in range(first, first + images_per_batch):
        epoch, position = divmod(slot, length)
        if epoch not in orders:
            orders[epoch] = image_order(seed, epoch, num_images, groups, images_per_batch)
        out.append((slot, int(orders[epoch][position])))
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
    groups: np.ndarray | None = None,
) -> list[ImagePlan]:
    """This rank's mini-batch at ``iteration``: images, flips and RoIs, reproducibly.
    ``groups``: one shape group per image, to batch images of one shape together (or None)."""
    plans = []
    for slot, image in slot_images(
        seed, iteration, len(labels_per_image), images_per_batch, rank, world_size, groups
    ):
        rng = np.random.default_rng([seed, _SLOT_STREAM, slot])
        flipped = bool(flip and rng.random() < 0.5)
        rois, num_fg = sample_rois(labels_per_image[image], rng, rois_per_image, fg_fraction)
        plans.append(ImagePlan(image, flipped, rois, num_fg))
    return plans
