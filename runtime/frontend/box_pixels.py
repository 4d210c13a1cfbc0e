"""An object's own pixels inside a 2D detector's box, and the initial 3D centre they give.

A detector's box holds the object and whatever lies around and behind it: floor, wall, the table
in front of a chair. a3d's own proposals are segments, so their depth median is the object's; a
box's is not. Here the object is the depth layer that the box's central part mostly lies in: the
mode of a histogram of the depth over the box's inner half. The pixels of the whole box whose
depth lies within ``reach`` of that mode (the class's half extent, so that a deep sofa keeps its
back and a chair loses the wall behind it) are the object. Its centre is then made as
a3d.runtime.frontend.lifting makes a proposal's: the median raw depth of those pixels (the
hole-filled depth where none is raw) at the back-projection of their centroid pixel.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.frontend.lifting import LiftedProposals
from a3d.runtime.structures.geometry import CameraLike, backproject

BIN_M = 0.05  # depth histogram bin for the mode (a chair's seat is a few bins deep)
INNER = 0.25  # the inner half: the box shrunk by a quarter of its size on each side
MIN_PIXELS = 20  # fewer raw pixels than this in the inner half: the filled depth is used
NOISE_M = 0.10  # the reach's allowance for sensor noise


def class_reach(candidates: np.ndarray, mean_sizes: np.ndarray) -> np.ndarray:
    """Per box, how far from its depth mode its object's pixels may lie: half the largest mean
    size of the classes it may be (``candidates`` (N, C) bool, ``mean_sizes`` (C, 3)), plus
    ``NOISE_M``."""
    half = 0.5 * np.asarray(mean_sizes).max(axis=1)
    return np.where(candidates, half[None, :], 0.0).max(axis=1) + NOISE_M


def object_masks_in_boxes(
    boxes: np.ndarray,
    reach: np.ndarray,
    depth_raw: np.ndarray,
    depth_filled: np.ndarray,
    voters: list[np.ndarray | None] | None = None,
) -> list[tuple[tuple[int, int], np.ndarray]]:
    """Per box, (top-left (x0, y0), mask of the box's crop): its object's pixels (module docstring).

    ``boxes`` (N, 4) [x1, y1, x2, y2] pixels, ``reach`` (N,) metres; depth maps (H, W) metres,
    raw 0 where missing. ``voters``: per box, an (H, W) bool of the pixels whose depth picks the
    object's layer instead of the box's inner half (a segmentation network's mask of its class,
    measured in docs/real-rooms.md), or None for the inner half."""
    height, width = depth_raw.shape
    depth = np.where(depth_raw > 0, depth_raw, depth_filled)
    out = []
    voters = voters or [None] * len(boxes)
    for (x1, y1, x2, y2), r, vote in zip(
        np.asarray(boxes, np.float64), np.asarray(reach, np.float64), voters, strict=True
    ):
        x0, y0 = int(np.clip(np.floor(x1), 0, width - 1)), int(np.clip(np.floor(y1), 0, height - 1))
        xe, ye = int(np.clip(np.ceil(x2), x0 + 1, width)), int(np.clip(np.ceil(y2), y0 + 1, height))
        crop = depth[y0:ye, x0:xe]
        h, w = crop.shape
        if vote is None:
            inner = crop[int(INNER * h) : max(int((1 - INNER) * h), int(INNER * h) + 1),
                         int(INNER * w) : max(int((1 - INNER) * w), int(INNER * w) + 1)]  # fmt: skip
        else:
            inner = crop[vote[y0:ye, x0:xe]]
        mode = _depth_mode(inner, depth_raw[y0:ye, x0:xe])
        mask = (crop > 0) & (np.abs(crop - mode) <= r) if mode > 0 else np.zeros_like(crop, bool)
        out.append(((x0, y0), mask))
    return out


def _depth_mode(inner: np.ndarray, raw_crop: np.ndarray) -> float:
    """The most common depth (bin centre) of the inner part's pixels; 0 where it has none."""
    values = inner[inner > 0]
    if values.size < MIN_PIXELS and (raw_crop > 0).sum() >= MIN_PIXELS:
        values = raw_crop[raw_crop > 0]  # a thin object (a chair's legs): the whole box's raw depth
    if values.size == 0:
        return 0.0
    bins = np.floor(values / BIN_M).astype(np.int64)
    low = int(bins.min())
    counts = np.bincount(bins - low)
    smooth = np.convolve(counts, [1, 2, 1], mode="same")  # a surface split over two bins counts once
    return (low + int(np.argmax(smooth)) + 0.5) * BIN_M


def lift_boxes(
    boxes: np.ndarray,
    reach: np.ndarray,
    depth_raw: np.ndarray,
    depth_filled: np.ndarray,
    K: CameraLike,
) -> LiftedProposals:
    """Initial centres of detector boxes (module docstring), in lifting's form: ``valid`` False
    where a box holds no depth at all."""
    return centres_of_masks(
        object_masks_in_boxes(boxes, reach, depth_raw, depth_filled), depth_raw, depth_filled, K
    )


def centres_of_masks(
    masks: list[tuple[tuple[int, int], np.ndarray]],
    depth_raw: np.ndarray,
    depth_filled: np.ndarray,
    K: CameraLike,
) -> LiftedProposals:
    """``object_masks_in_boxes``'s masks as initial centres: the median raw depth of each mask's
    pixels (the filled depth where none is raw) at the back-projection of their centroid."""
    n = len(masks)
    u, v, z = np.zeros(n), np.zeros(n), np.zeros(n)
    from_filled = np.zeros(n, bool)
    for i, ((x0, y0), mask) in enumerate(masks):
        ys, xs = np.nonzero(mask)
        if not len(xs):
            continue
        h, w = mask.shape
        raw = depth_raw[y0 : y0 + h, x0 : x0 + w][ys, xs]
        raw = raw[raw > 0]
        from_filled[i] = raw.size == 0
        z[i] = np.median(raw) if raw.size else np.median(depth_filled[y0 : y0 + h, x0 : x0 + w][ys, xs])
        u[i], v[i] = x0 + xs.mean(), y0 + ys.mean()
    valid = z > 0
    centers = backproject(u, v, z, K)
    centers[~valid] = 0.0
    return LiftedProposals(centers, valid, from_filled & valid)
