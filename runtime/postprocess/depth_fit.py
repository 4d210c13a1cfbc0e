"""Doors slid onto the surface the depth shows: a thin box placed where it claims no free space.

Why: a door is a slab a few centimetres thick in a wall. A centre regressed a few tens of
centimetres off puts the whole box in front of the wall or behind it, and a thin box that far off
overlaps its door by next to nothing. The depth says where the door is: its box should hold the
depth points of its 2D box and leave free the space the camera sees through. Each door detection
scoring ``MIN_SCORE`` or more keeps its size and yaw (after the walls' turn, wall_axes) and is
moved on a grid of horizontal offsets, ``REACH_M`` either way in ``STEP_M`` steps, to where
``support - seen_through`` is largest: ``support`` the share of its 2D box's depth points that lie
in the box grown by ``MARGIN_M`` (as depth_support counts them), ``seen_through`` the share of
points spread through the box's volume behind which the camera sees (observed depth more than
``SEE_M`` beyond them). Only doors: chairs, tables and basins are not solid (the camera sees
between their legs and into them), and boxes, counters and beds lost where it was tried on
them (docs/real-rooms.md, step 7).
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.postprocess.depth_support import MARGIN_M, SampledDepth, box_points
from a3d.runtime.structures.boxes import CENTER, THETA, H, L, W
from a3d.runtime.structures.classes import class_mask
from a3d.runtime.structures.geometry import (
    CameraLike,
    depth_seen_at,
    evenly_spread,
    points_in_box,
    turned_by_yaw,
)

FITTED = ("door",)
REACH_M, STEP_M = 0.3, 0.05
SEE_M = 0.10
MIN_SCORE = 0.05
MAX_POINTS = 4000  # of a door's depth points (box_points): x 169 candidate places, some 16 MB of offsets
VOLUME_SAMPLES = 6  # per axis of the box
NEAR_M = 0.1  # volume samples nearer the camera than this are not looked at


def _offsets() -> np.ndarray:
    steps = np.arange(-REACH_M, REACH_M + STEP_M / 2, STEP_M)
    dx, dz = np.meshgrid(steps, steps, indexing="ij")
    return np.stack([dx.ravel(), np.zeros(dx.size), dz.ravel()], axis=1)  # (G, 3) tilt frame


STAY = int(np.argmin(np.abs(_offsets()).sum(axis=1)))  # the zero offset's row


def fitted_classes() -> np.ndarray:
    """(19,) bool: the classes whose boxes are fitted."""
    return class_mask(FITTED)


def fit_to_depth(
    sampled: SampledDepth, boxes2d: np.ndarray, boxes3d: np.ndarray, class_idx: np.ndarray, scores: np.ndarray
) -> np.ndarray:
    """``boxes3d`` (N, 7; camera-frame centre, yaw in the tilt frame of ``sampled.R_tilt``) with the
    fitted classes' (``class_idx`` 0-based, ``scores``) moved as the module docstring says, in the
    frame's depth (depth_support.sample_depth); ``boxes2d`` (N, 4) the detections' 2D boxes."""
    boxes = np.array(boxes3d, np.float64, copy=True)
    chosen = np.flatnonzero(fitted_classes()[np.asarray(class_idx)] & (np.asarray(scores) >= MIN_SCORE))
    if not len(chosen):
        return boxes
    R, depth, K = sampled.R_tilt, sampled.depth, sampled.K
    offsets = _offsets()
    grid = (np.arange(VOLUME_SAMPLES) + 0.5) / VOLUME_SAMPLES - 0.5
    unit = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3)  # along l, h, w
    for i, held in zip(chosen, box_points(sampled, np.asarray(boxes2d)[chosen]), strict=True):
        if not len(held):
            continue
        box = boxes[i]
        centres = R @ box[CENTER] + offsets  # (G, 3) tilt frame, offset 0 among them
        held = evenly_spread(held, MAX_POINTS)
        # The box moved by an offset holds what it held of the points moved back by it.
        support = points_in_box(held[None] - offsets[:, None], box, R, MARGIN_M, MARGIN_M).mean(axis=1)
        volume = turned_by_yaw(unit * box[[L, H, W]], box[THETA])  # tilt offsets of the samples
        camera = (volume[None] + centres[:, None]) @ R  # (G, S, 3): p_cam = R^T p_tilt
        seen = _seen_through(camera, depth, K)
        fit = support - seen
        best = int(np.argmax(fit))
        if fit[best] > fit[STAY]:  # a tie keeps the regressed centre
            boxes[i, CENTER] = R.T @ centres[best]
    return boxes


def _seen_through(camera: np.ndarray, depth: np.ndarray, K: CameraLike) -> np.ndarray:
    """(G,) per candidate, the share of its volume samples (G, S, 3 camera frame) that project onto
    a depth pixel lying more than ``SEE_M`` beyond them (of those that project onto one)."""
    observed = depth_seen_at(camera, depth, K, near_m=NEAR_M)
    on = observed > 0
    seen = on & (observed > camera[..., 2] + SEE_M)  # a sample behind the camera is not seen through
    return seen.sum(axis=1) / np.maximum(on.sum(axis=1), 1)
