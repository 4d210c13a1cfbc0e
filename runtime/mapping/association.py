"""Which of a frame's detections are which of the map's objects.

A detection (in the map's gravity-aligned frame) may be an object of the map when it has the
same class, its centre is within ``max_centre_m`` of the object's and their 3D IoU is at least
``min_iou`` (both gates: a small object's IoU collapses with a few centimetres of error, and a
large one's centre may wander inside it). Among the pairs that pass, the highest IoU is taken
first, then the next one whose detection and object are both still free: each detection is one
object at most and each object is seen once per frame at most. Objects do not move (docs/mapping.md
"The object map"), so nothing predicts where they will be: the gates compare boxes as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.runtime.structures.boxes import CENTER
from a3d.runtime.structures.geometry import iou_3d

IDENTITY = np.eye(3)


@dataclass(frozen=True)
class AssociationGates:
    """``max_centre_m``: largest centre distance of a pair; ``min_iou``: smallest 3D IoU."""

    max_centre_m: float = 0.6
    min_iou: float = 0.05


def associate(
    det_boxes: np.ndarray,
    det_classes: np.ndarray,
    obj_boxes: np.ndarray,
    obj_classes: np.ndarray,
    gates: AssociationGates = AssociationGates(),
) -> list[tuple[int, int]]:
    """(detection row, object row) pairs, greedy by 3D IoU among the gated pairs (module docstring).
    Boxes are (N, 7) and (M, 7) in one gravity-aligned frame; classes 0-based class indices."""
    det_boxes, obj_boxes = np.asarray(det_boxes).reshape(-1, 7), np.asarray(obj_boxes).reshape(-1, 7)
    if not len(det_boxes) or not len(obj_boxes):
        return []
    iou = iou_3d(det_boxes, obj_boxes, IDENTITY)
    distance = np.linalg.norm(det_boxes[:, None, CENTER] - obj_boxes[None, :, CENTER], axis=2)
    same = np.asarray(det_classes)[:, None] == np.asarray(obj_classes)[None, :]
    ok = same & (distance <= gates.max_centre_m) & (iou >= gates.min_iou)
    rows, cols = np.nonzero(ok)
    order = np.lexsort((distance[rows, cols], -iou[rows, cols]))
    pairs, used_d, used_o = [], set(), set()
    for k in order:
        i, j = int(rows[k]), int(cols[k])
        if i not in used_d and j not in used_o:
            used_d.add(i)
            used_o.add(j)
            pairs.append((i, j))
    return sorted(pairs)
