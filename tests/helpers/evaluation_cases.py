"""Unit-cube truths and detections for the evaluation tests (metric and protocols).

Unit cubes at theta = 0 with R_tilt = I, shifted along x: two whose centres differ by d
(0 <= d <= 1) overlap in a (1 - d) x 1 x 1 slab, so their 3D IoU is (1 - d) / (1 + d).
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.evaluation.metric import FrameTruth
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import class_index

CHAIR, TABLE, LAMP = class_index("chair"), class_index("table"), class_index("lamp")
EYE = np.eye(3)


def cube(x: float, z: float = 3.0, size: float = 1.0, theta: float = 0.0) -> list[float]:
    return [x, 0.0, z, size, size, size, theta]


def truth(class_ids, boxes, R_tilt=EYE) -> FrameTruth:
    return FrameTruth(np.asarray(class_ids, dtype=np.int64), np.asarray(boxes, float).reshape(-1, 7), R_tilt)


def dets(frame, class_ids, scores, boxes3d, boxes2d=None, R_tilt=EYE) -> FrameDetections:
    n = len(scores)
    if boxes2d is None:  # disjoint 2D boxes: the default NMS keeps every detection
        boxes2d = [[20.0 * i, 0.0, 20.0 * i + 10.0, 10.0] for i in range(n)]
    return FrameDetections(
        frame=frame,
        R_tilt=np.asarray(R_tilt, float),
        class_ids=np.asarray(class_ids, dtype=np.int64).reshape(n),
        scores=np.asarray(scores, float).reshape(n),
        boxes2d=np.asarray(boxes2d, float).reshape(n, 4),
        boxes3d=np.asarray(boxes3d, float).reshape(n, 7),
    )
