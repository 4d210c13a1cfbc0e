"""Which a3d class each ImageNet class stands for: many to one, the rest (most of the 1000) none.

Why: an ImageNet classifier knows "chiffonier" and "four-poster", not a3d's "dresser" and "bed".
A crop's probability of an a3d class is the sum of its ImageNet classes' probabilities. Keys are
the first name of an ImageNet label ("chiffonier, commode" -> "chiffonier"). Counter and night
stand have no ImageNet class; "chest" (a lidded storage chest), "china cabinet" and "entertainment
center" stand for furniture that NYUv2 labels none of the 19, so they are left out.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES

IMAGENET_CLASS_MAP: dict[str, str] = {
    "bathtub": "bathtub", "tub": "bathtub",
    "four-poster": "bed", "quilt": "bed", "crib": "bed",
    "bookcase": "bookshelf", "library": "bookshelf",
    "carton": "box", "crate": "box",
    "folding chair": "chair", "rocking chair": "chair", "barber chair": "chair", "throne": "chair",
    "desk": "desk",
    "sliding door": "door",
    "chiffonier": "dresser", "wardrobe": "dresser", "file": "dresser",
    "ashcan": "garbage bin",
    "table lamp": "lamp", "lampshade": "lamp",
    "monitor": "monitor", "screen": "monitor", "desktop computer": "monitor",
    "pillow": "pillow",
    "washbasin": "sink",
    "studio couch": "sofa",
    "dining table": "table",
    "television": "television",
    "toilet seat": "toilet",
}  # fmt: skip


def first_name(label: str) -> str:
    """An ImageNet label's first name: "chiffonier, commode" -> "chiffonier"."""
    return label.split(",")[0].strip()


def label_matrix(labels: tuple[str, ...], class_map: dict[str, str] = IMAGENET_CLASS_MAP) -> np.ndarray:
    """(L, 19) float32: row l is one-hot on the a3d class label l stands for, zero where none, so
    that ``probs @ matrix`` sums a crop's probabilities per a3d class."""
    matrix = np.zeros((len(labels), NUM_CLASSES), np.float32)
    for i, label in enumerate(labels):
        target = class_map.get(first_name(label))
        if target is not None:
            matrix[i, CLASSES.index(target)] = 1.0
    return matrix
