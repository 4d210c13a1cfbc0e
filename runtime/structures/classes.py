"""The 19 NYUv2 object classes of Deng & Latecki (docs/conventions.md "Task").

Index 0 of the network's 20-way softmax is background; class ``CLASSES[i]`` is
softmax index ``i + 1``.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

import numpy as np

CLASSES: tuple[str, ...] = (
    "bathtub",
    "bed",
    "bookshelf",
    "box",
    "chair",
    "counter",
    "desk",
    "door",
    "dresser",
    "garbage bin",
    "lamp",
    "monitor",
    "night stand",
    "pillow",
    "sink",
    "sofa",
    "table",
    "television",
    "toilet",
)
NUM_CLASSES = len(CLASSES)  # 19 object classes
NUM_OUTPUTS = NUM_CLASSES + 1  # softmax width, background first
BACKGROUND = 0

_INDEX = {name: i for i, name in enumerate(CLASSES)}


def to_softmax(class_ids: np.ndarray | int) -> np.ndarray:
    """Softmax indices (background 0) of 0-based CLASSES indices: the one place the offset is added."""
    return np.asarray(class_ids) + 1


def from_softmax(labels: np.ndarray | int) -> np.ndarray:
    """0-based CLASSES indices of softmax indices > 0 (background has none)."""
    return np.asarray(labels) - 1


def class_mask(names: Iterable[str]) -> np.ndarray:
    """(NUM_CLASSES,) bool, True at the classes named (each one of CLASSES; ValueError otherwise)."""
    mask = np.zeros(NUM_CLASSES, bool)
    mask[[class_index(name) for name in names]] = True
    return mask


def class_index(name: str) -> int:
    """0-based index of a class name in CLASSES; ValueError names the unknown class."""
    try:
        return _INDEX[name]
    except KeyError:
        raise ValueError(f"unknown class name {name!r} (expected one of: {', '.join(CLASSES)})") from None


CLASS_ALIASES = {"tv": "television", "nightstand": "night stand", "garbagebin": "garbage bin"}
"""Other spellings of the 19 class names (NYUv2, SUN RGB-D), keyed lower-case without spaces or "_"."""


def normalize_class_name(name: str) -> str | None:
    """The a3d class of a data set's label ('night_stand' -> 'night stand', 'tv' -> 'television'), or None."""
    key = re.sub(r"\s+", " ", name.strip().lower().replace("_", " "))
    key = CLASS_ALIASES.get(key.replace(" ", ""), key)
    return key if key in CLASSES else None


# One colour per class (RGB, tab20-like, distinct at a glance), shared by every view and plot.
CLASS_COLORS_RGB: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
    (174, 199, 232),
    (255, 187, 120),
    (152, 223, 138),
    (255, 152, 150),
    (197, 176, 213),
    (196, 156, 148),
    (247, 182, 210),
    (219, 219, 141),
    (158, 218, 229),
)
