"""How consistent a detector is over a posed recording, without labels: measured on its object map.

A static object seen from many poses should be detected in every frame that sees it, in the same
place and at the same size; a detection that no other frame repeats is probably wrong. So, for
the map's objects supported by at least ``min_support`` frames (docs/mapping.md "Consistency"):

* **re-detection rate**: frames that detected the object over the frames that should have seen it
  (detected + missed, a3d.runtime.mapping.object_map);
* **jitter**: the spread of the object's observations about its fused box in the world: RMS
  centre distance (m), RMS size deviation (in log space, read as a fraction), RMS yaw deviation
  (degrees, modulo pi with the l/w symmetry);

and over all mapped detections, the **spurious rate**: the share that ended in objects with less
support (dropped ones included). With ground truth, ``against_world`` scores the map itself: its
supported objects against the world's boxes (same class, 3D IoU >= 0.25, greedy by score).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.runtime.mapping.fusion import align_boxes
from a3d.runtime.mapping.object_map import MapObject, ObjectMap
from a3d.runtime.mapping.world_boxes import WorldBoxes
from a3d.runtime.structures.boxes import CENTER, SIZE, THETA
from a3d.runtime.structures.classes import class_index
from a3d.runtime.structures.geometry import iou_3d


@dataclass(frozen=True)
class ObjectConsistency:
    """One supported object: its id, class, support, expected frames and the measures above."""

    id: int
    cls: str
    support: int
    expected: int
    redetection: float
    centre_jitter_m: float
    size_jitter: float
    yaw_jitter_deg: float


@dataclass(frozen=True)
class MapConsistency:
    """The supported objects' measures, and the mapped detections and how many were spurious."""

    objects: list[ObjectConsistency]
    detections: int
    spurious: int

    @property
    def spurious_rate(self) -> float:
        return self.spurious / max(self.detections, 1)

    def median(self, name: str) -> float:
        """The median of one measure over the supported objects (NaN without any)."""
        values = [getattr(o, name) for o in self.objects]
        return float(np.median(values)) if values else float("nan")


def object_consistency(obj: MapObject) -> ObjectConsistency:
    """The measures of one object from its observations and fused box."""
    observed = align_boxes(np.array(obj.observations), float(obj.box[THETA]))
    fused = align_boxes(obj.box[None], float(obj.box[THETA]))[0]
    centre = np.linalg.norm(observed[:, CENTER] - fused[CENTER], axis=1)
    size = np.log(observed[:, SIZE] / fused[SIZE])
    yaw = observed[:, THETA] - fused[THETA]
    return ObjectConsistency(
        obj.id,
        obj.cls,
        obj.support,
        obj.support + obj.misses,
        obj.support / (obj.support + obj.misses),
        _rms(centre),
        float(np.expm1(_rms(size))),
        float(np.degrees(_rms(yaw))),
    )


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def map_consistency(world_map: ObjectMap, min_support: int = 3) -> MapConsistency:
    """The measures of every object supported by ``min_support`` frames, and the spurious rate."""
    every = world_map.objects + world_map.dropped
    supported = [o for o in world_map.objects if o.support >= min_support]
    detections = sum(len(o.observations) for o in every)
    spurious = sum(len(o.observations) for o in every if o.support < min_support)
    return MapConsistency([object_consistency(o) for o in supported], detections, spurious)


@dataclass(frozen=True)
class MapAccuracy:
    """The map against ground truth: supported objects, true ones, world objects, and the true
    ones' centre errors (metres) and size errors (the mean relative error of length, width and
    height, the footprint's longer side as length on both)."""

    objects: int
    true: int
    world: int
    centre_errors_m: list[float]
    size_errors: list[float]

    @property
    def precision(self) -> float:
        return self.true / max(self.objects, 1)

    @property
    def recall(self) -> float:
        return self.true / max(self.world, 1)


def against_world(
    world_map: ObjectMap,
    world: WorldBoxes,
    min_support: int = 3,
    iou_threshold: float = 0.25,
    seen: set[int] | None = None,
) -> MapAccuracy:
    """The map's objects supported by ``min_support`` frames against ``world``'s boxes (in the
    same frame: a3d-synth's world, where the map's turn is the identity), greedy by fused score;
    ``seen`` (world ids) limits the world to the objects the recording saw."""
    objects = sorted((o for o in world_map.objects if o.support >= min_support), key=lambda o: -o.score())
    keep = [i for i, k in enumerate(world.ids) if seen is None or int(k) in seen]
    boxes, classes = world.boxes[keep], [class_index(world.classes[i]) for i in keep]
    iou = iou_3d(np.array([o.box for o in objects]).reshape(-1, 7), boxes.reshape(-1, 7), np.eye(3))
    taken: set[int] = set()
    errors, size_errors = [], []
    for row, obj in enumerate(objects):
        candidates = [j for j in range(len(keep)) if classes[j] == obj.class_id and j not in taken]
        if not candidates:
            continue
        j = max(candidates, key=lambda c: iou[row, c])
        if iou[row, j] >= iou_threshold:
            taken.add(j)
            errors.append(float(np.linalg.norm(obj.box[CENTER] - boxes[j, CENTER])))
            ours, truth = _lwh(obj.box), _lwh(boxes[j])
            size_errors.append(float(np.mean(np.abs(ours - truth) / truth)))
    return MapAccuracy(len(objects), len(taken), len(keep), errors, size_errors)


def _lwh(box: np.ndarray) -> np.ndarray:
    """(length, width, height) with the footprint's longer side first, whatever the 7-vector's order."""
    return np.array([max(box[3], box[4]), min(box[3], box[4]), box[5]])
