"""Long boxes turned along their object: step 10 of the pipelines with a 2D detector.

Why: a box regressed from one RoI gets a long object's length right more often than which way it
runs: on the real frames a sofa along the wall and a dining table seen end on came out as boxes
across them, about a right angle off (looked at: docs/real-rooms.md), and a box a right angle off
overlaps its object by a fraction. The depth says which way the object runs: from above, what the
camera sees of a table's top or a sofa's front and seat is long along the object. So for each box
that is itself long (``l >= MIN_RATIO * w``: sofas, tables, counters, beds, desks, dressers), the
depth samples of its 2D box (the floor's left out) that lie round its centre, within its half
length and ``MARGIN_M`` across the floor and its height and ``MARGIN_M`` up and down, whichever
way it runs, are taken; where their footprint is long (the square root of its two principal
variances' ratio ``MIN_ELONGATION`` or more) and runs more than ``TURN_DEG`` off the box's
length, the box is turned by a right angle about its centre. It runs after step 5, so that it
moves no score, and before step 9, which then grows the turned box to hold its object's depth.
Doors are not turned: a door's thin box stands in its wall (steps 6 and 7).
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.postprocess.depth_support import MIN_SCORE, SampledDepth, object_samples
from a3d.runtime.structures.boxes import CENTER, THETA, L, W, local_half_sizes
from a3d.runtime.structures.classes import class_mask
from a3d.runtime.structures.geometry import canonical_boxes, turned_by_yaw

MIN_RATIO = 1.4
MIN_ELONGATION = 1.5
TURN_DEG = 45.0
MARGIN_M = 0.1
MIN_POINTS = 50  # fewer samples round a box say nothing of which way its object runs
KEPT = ("door",)


def along_depth(
    sampled: SampledDepth, boxes2d: np.ndarray, boxes3d: np.ndarray, class_idx: np.ndarray,
    scores: np.ndarray, floor: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """``boxes3d`` (N, 7; camera-frame centres, yaws in ``sampled.R_tilt``'s tilt frame) with the
    long ones scoring ``MIN_SCORE`` or more turned along their object's depth samples (module
    docstring); ``class_idx`` 0-based, ``floor`` step 8's plane or None."""
    boxes3d = np.array(boxes3d, np.float64)
    long = (boxes3d[:, L] >= MIN_RATIO * boxes3d[:, W]) & ~class_mask(KEPT)[np.asarray(class_idx)]
    chosen = np.flatnonzero(long & (np.asarray(scores) >= MIN_SCORE))
    if not np.isfinite(MIN_ELONGATION) or not len(chosen):
        return boxes3d
    R = sampled.R_tilt
    for i, points in zip(chosen, object_samples(sampled, np.asarray(boxes2d)[chosen], floor), strict=True):
        box = boxes3d[i]
        offsets = points - R @ box[CENTER]
        half_l, half_h, _ = local_half_sizes(box[None])[0]
        round_it = (np.hypot(offsets[:, 0], offsets[:, 2]) <= half_l + MARGIN_M) & (
            np.abs(offsets[:, 1]) <= half_h + MARGIN_M
        )
        footprint = offsets[round_it][:, [0, 2]]
        if len(footprint) < MIN_POINTS:
            continue
        variances, axes = np.linalg.eigh(np.cov(footprint, rowvar=False))  # ascending
        if variances[1] < MIN_ELONGATION**2 * max(variances[0], 1e-12):
            continue
        length = turned_by_yaw(np.array([1.0, 0.0, 0.0]), box[THETA])[[0, 2]]  # the box's l axis, (x, z)
        if abs(float(axes[:, 1] @ length)) < np.cos(np.radians(TURN_DEG)):
            box[THETA] += np.pi / 2
    boxes3d[chosen] = canonical_boxes(boxes3d[chosen])
    return boxes3d
