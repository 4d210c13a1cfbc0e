"""The 19 NYUv2 object classes of Deng & Latecki (docs/conventions.md "Task").

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
