"""``world_boxes.json``: the objects of a scene as boxes in a gravity-aligned world, drawn once.

    {"objects": [{"class": "chair", "centre": [x, y, z], "size": [l, w, h], "yaw": theta, "id": 3}]}

The world is a3d's (a3d.runtime.mapping.world: y along gravity, pointing down, metres); ``yaw`` is
``atan2(dx, dz)`` of the box's orientation vector about that y axis, radians; ``size`` the two
horizontal extents and the height. ``id`` (optional, a non-negative integer, unique) names the
object across frames. a3d-synth ``--sequence`` writes this file, ``a3d-labels`` reads it (docs/mapping.md).
Reading is strict: every problem is one ``InputError`` line naming the file and the object.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.image_io import read_bytes
from a3d.runtime.io.json_input import is_finite_number, parse_json
from a3d.runtime.structures.boxes import CENTER, SIZE, THETA, boxes_array
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import canonical_boxes

WORLD_BOXES_FILE = "world_boxes.json"
_KEYS = ("class", "centre", "size", "yaw", "id")


@dataclass(frozen=True)
class WorldBoxes:
    """N objects: class names, boxes (N, 7) in the world (canonical: l >= w, yaw in [-pi/2, pi/2]),
    ids (N,) (their position in the file where the file gives none)."""

    classes: list[str]
    boxes: np.ndarray
    ids: np.ndarray

    def __len__(self) -> int:
        return len(self.classes)


def write_world_boxes(path: str | os.PathLike, boxes: WorldBoxes) -> None:
    """Write the file atomically, one object per line."""
    rows = []
    for name, box, k in zip(boxes.classes, np.asarray(boxes.boxes, np.float64), boxes.ids, strict=True):
        centre, size, yaw = box[CENTER].tolist(), box[SIZE].tolist(), float(box[THETA])
        rows.append(json.dumps({"class": name, "centre": centre, "size": size, "yaw": yaw, "id": int(k)}))
    atomic_write_bytes(path, ('{"objects": [\n  ' + ",\n  ".join(rows) + "\n]}\n").encode("utf-8"))


def read_world_boxes(path: str | os.PathLike) -> WorldBoxes:
    """The file's objects, validated (InputError "PATH: objects[i].key ..." on the first problem)."""
    path = Path(path)
    document = parse_json(read_bytes(path), str(path))
    if not isinstance(document, dict) or not isinstance(document.get("objects"), list):
        raise InputError(f'{path}: expected an object {{"objects": [...]}}')
    classes, rows, ids = [], [], []
    for i, obj in enumerate(document["objects"]):
        what = f"{path}: objects[{i}]"
        if not isinstance(obj, dict):
            raise InputError(f"{what} must be an object")
        unknown = [key for key in obj if key not in _KEYS]
        missing = [key for key in _KEYS[:4] if key not in obj]
        if unknown or missing:
            problem = f"unknown key {unknown[0]!r}" if unknown else f"lacks {missing[0]!r}"
            raise InputError(f"{what}: {problem} (keys: {', '.join(_KEYS)}; id optional)")
        if obj["class"] not in CLASSES:
            raise InputError(f"{what}.class {obj['class']!r} is not one of the 19 classes")
        centre, size = (_numbers(obj[key], what, key) for key in ("centre", "size"))
        yaw = obj["yaw"]
        if not (size > 0).all():
            raise InputError(f"{what}.size must be three positive extents l, w, h, got {size.tolist()}")
        if not is_finite_number(yaw):
            raise InputError(f"{what}.yaw must be a finite number of radians, got {yaw!r}")
        k = obj.get("id", i)
        if isinstance(k, bool) or not isinstance(k, int) or k < 0:
            raise InputError(f"{what}.id must be a non-negative integer, got {k!r}")
        classes.append(obj["class"])
        rows.append([*centre, *size, float(yaw)])
        ids.append(k)
    if len(set(ids)) != len(ids):
        raise InputError(f"{path}: object ids must be unique")
    boxes = canonical_boxes(boxes_array(rows, len(rows)))
    return WorldBoxes(classes, boxes, np.array(ids, np.int64))


def _numbers(value: Any, what: str, key: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3 or not all(is_finite_number(v) for v in value):
        raise InputError(f"{what}.{key} must be 3 finite numbers, got {json.dumps(value)[:60]}")
    return np.array(value, np.float64)
