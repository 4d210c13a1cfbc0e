"""3D boxes grown to hold what the depth shows of their object: step 9 of the pipelines with a 2D detector.

Why: an amodal box holds all of its object, and what the camera sees of the object is in the
depth inside its 2D box. A box regressed from one RoI often stops short of it: a chair's back or
a monitor's screen out of its box, a door a few centimetres off the wall it hangs in. Of the depth
samples in a detection's 2D box, those within ``MARGIN_M`` of its 3D box are taken for its
object's surface (samples farther off are the background, a neighbour or the floor), and each face
moves out, never in, to hold them, less the outermost ``TRIM_PERCENT`` along each of the box's axes
(the sensor's stray depth): a face moves by at most ``MARGIN_M``. The floor's samples are left out
(round an object's foot they would widen its footprint along the floor). It runs after step 5 and moves no
score, only boxes. Growing every box by a few centimetres instead, the depth unseen, loses (4 cm:
mAP@0.5 23.7 -> 18.0 on the frames below), so what counts is where the object's points are.

``MARGIN_M`` was chosen on the 350 a3d-synth frames of seed 2031 that no other number uses
(``python -m bench.depth_steps hold``; docs/real-rooms.md, step 9), ``TRIM_PERCENT`` there once.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.postprocess.depth_support import MIN_SCORE, SampledDepth, object_samples
from a3d.runtime.structures.boxes import CENTER, LOCAL_XYZ_EXTENTS, THETA, local_half_sizes
from a3d.runtime.structures.geometry import canonical_boxes, turned_by_yaw

MARGIN_M = 0.1
TRIM_PERCENT = 3.0
MIN_POINTS = 30  # fewer samples near a box say nothing of where its object's surface ends


def hold_depth(
    sampled: SampledDepth, boxes2d: np.ndarray, boxes3d: np.ndarray, scores: np.ndarray,
    floor: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """``boxes3d`` (N, 7; camera-frame centres, yaws in ``sampled.R_tilt``'s tilt frame), those
    scoring ``MIN_SCORE`` or more grown to hold their object's depth samples (module docstring).
    With the frame's ``floor`` (floor_contact.frame_floor's plane), the floor's samples
    (depth_support.object_samples) are not an object's: no box grows into the floor or along it."""
    boxes3d = np.array(boxes3d, np.float64)
    chosen = np.flatnonzero(np.asarray(scores) >= MIN_SCORE)
    if MARGIN_M <= 0 or not len(chosen):
        return boxes3d
    R = sampled.R_tilt
    for i, points in zip(chosen, object_samples(sampled, np.asarray(boxes2d)[chosen], floor), strict=True):
        box = boxes3d[i]
        centre = R @ box[CENTER]
        local = turned_by_yaw(points - centre, -box[THETA])  # along the box's l, h, w
        half = local_half_sizes(box[None])[0]
        near = local[np.all(np.abs(local) <= half + MARGIN_M, axis=1)]
        if len(near) < MIN_POINTS:
            continue
        ordered, trim = np.sort(near, axis=0), int(TRIM_PERCENT / 100 * (len(near) - 1))
        low, high = ordered[trim], ordered[-1 - trim]
        low, high = np.minimum(-half, low), np.maximum(half, high)
        box[CENTER] = R.T @ (centre + turned_by_yaw((low + high) / 2, box[THETA]))
        box[LOCAL_XYZ_EXTENTS] = high - low
    boxes3d[chosen] = canonical_boxes(boxes3d[chosen])  # l >= w again where w grew past l
    return boxes3d
