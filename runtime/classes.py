"""The 19 NYUv2 object classes of Deng & Latecki (SPEC.md "Task").

Index 0 of the network's 20-way softmax is background; class ``CLASSES[i]`` is
softmax index ``i + 1``.
"""

from __future__ import annotations

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


def class_index(name: str) -> int:
    """0-based index of a class name in CLASSES; ValueError names the unknown class."""
    try:
        return _INDEX[name]
    except KeyError:
        raise ValueError(f"unknown class name {name!r} (expected one of: {', '.join(CLASSES)})") from None
