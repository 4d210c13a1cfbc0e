"""Which a3d classes a 2D detector's classes stand for: many to one, the rest dropped.

Why: a COCO detector knows "couch" and "dining table", not a3d's "sofa" and "table", and most of
its classes (person, cup, ...) are none of a3d's 19. A class may stand for several a3d classes
("tv" is a monitor or a television; "couch" a sofa or, as COCO's annotators often box an
armchair, a chair): the pipeline picks among those candidates with the 3D network's
probabilities. A class map file is a JSON object ``{"detector class": "a3d class" | ["a3d
class", ...]}``; an empty list drops a class.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.json_input import parse_json
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES

# COCO's classes that are a3d's, under YOLOX's spellings and Darknet's (sofa, diningtable, tvmonitor).
COCO_CLASS_MAP: dict[str, tuple[str, ...]] = {
    "chair": ("chair",),
    "couch": ("sofa", "chair"),
    "sofa": ("sofa",),
    "bed": ("bed",),
    "dining table": ("table",),
    "diningtable": ("table",),
    "toilet": ("toilet",),
    "tv": ("monitor", "television"),
    "tvmonitor": ("monitor", "television"),
    "sink": ("sink",),
}


@dataclass(frozen=True)
class CompiledMap:
    """A class map over one detector's classes, indexed by its class index."""

    candidates: np.ndarray  # (C, 19) bool: the a3d classes each detector class stands for
    first: np.ndarray  # (C,) int64: the CLASSES index of its first candidate, -1 where dropped

    @property
    def kept(self) -> np.ndarray:
        """(C,) bool: the detector classes the map keeps."""
        return self.first >= 0


def read_class_map(path: Path) -> dict[str, tuple[str, ...]]:
    """A class map file; a value outside a3d's 19 classes is an InputError naming the file and it."""
    try:
        text = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read the class map ({e.strerror or e})") from None
    doc = parse_json(text, str(path), "class map")
    if not isinstance(doc, dict):
        raise InputError(f'{path}: a class map is a JSON object {{"detector class": "a3d class" | [...]}}')
    mapped = {}
    for key, value in doc.items():
        targets = [value] if isinstance(value, str) else value
        if not (isinstance(targets, list) and all(isinstance(t, str) for t in targets)):
            raise InputError(f"{path}: {key!r} must map to an a3d class name or a list of them")
        unknown = [t for t in targets if t not in CLASSES]
        if unknown:
            known = ", ".join(CLASSES)
            raise InputError(f"{path}: {key!r} maps to {unknown[0]!r}, not an a3d class ({known})")
        mapped[key] = tuple(dict.fromkeys(targets))
    if not any(mapped.values()):
        raise InputError(f"{path}: the class map names no a3d class")
    return mapped


def compile_map(class_map: dict[str, tuple[str, ...]], names: tuple[str, ...]) -> CompiledMap:
    """The map over ``names``; keys that are none of them are ignored (one map may serve several
    detectors), so a map may keep no class at all: the caller says so."""
    candidates = np.zeros((len(names), NUM_CLASSES), bool)
    first = np.full(len(names), -1, np.int64)
    for i, name in enumerate(names):
        targets = class_map.get(name, ())
        if targets:
            candidates[i, [CLASSES.index(t) for t in targets]] = True
            first[i] = CLASSES.index(targets[0])
    return CompiledMap(candidates, first)
