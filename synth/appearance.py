"""Class-typical materials: the optional tie between an object's class and what it is made of.

By default (``SceneConfig.appearance = "independent"``) every furniture model draws its
materials from the frame's palette whatever its class, so colour and texture say nothing about
the class and a colour-only network must work from shading and silhouettes alone. Real rooms
are not like that: toilets, sinks and bathtubs are white ceramic, screens are black, beds carry
light bedding, boxes are cardboard, case furniture is wood or paint. With ``"typical"`` each
model, with probability ``SceneConfig.typical_share``, takes the materials of the slots named in
``CLASS_FAMILIES`` from one of its class's families (the other slots, and the other models, keep
the palette). Families are shared by several classes, and a family's colours and textures vary,
so the appearance hints at the class without identifying it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.synth.shading import Materials, material_texture, stack_materials


@dataclass(frozen=True)
class Family:
    """A kind of material: texture kinds and their weights, saturation, value and hue ranges
    (OpenCV's 0-180 hue) and the gloss range."""

    kinds: tuple[str, ...]
    weights: tuple[float, ...]
    sat: tuple[float, float]
    val: tuple[float, float]
    hue: tuple[float, float] = (0.0, 180.0)
    gloss: tuple[float, float] = (0.0, 0.1)


FAMILIES: dict[str, Family] = {
    "wood": Family(("wood", "mottled"), (0.8, 0.2), (0.35, 0.75), (0.15, 0.65), (6.0, 22.0), (0.0, 0.2)),
    "paint": Family(("plain", "mottled"), (0.7, 0.3), (0.0, 0.3), (0.55, 0.95), gloss=(0.0, 0.2)),
    "fabric": Family(
        ("fabric", "mottled", "checker", "stripes"), (0.55, 0.25, 0.1, 0.1), (0.1, 0.65), (0.15, 0.8)
    ),
    "bedding": Family(("plain", "fabric", "stripes"), (0.5, 0.35, 0.15), (0.0, 0.3), (0.65, 0.95)),
    "ceramic": Family(("plain",), (1.0,), (0.0, 0.05), (0.85, 0.97), gloss=(0.35, 0.6)),
    "screen": Family(("plain",), (1.0,), (0.0, 0.1), (0.02, 0.1), gloss=(0.3, 0.6)),
    "metal": Family(("metal",), (1.0,), (0.0, 0.1), (0.35, 0.8), gloss=(0.3, 0.5)),
    "plastic": Family(("plain", "mottled"), (0.7, 0.3), (0.0, 0.7), (0.1, 0.9), gloss=(0.1, 0.3)),
    "cardboard": Family(
        ("plain", "mottled", "speckle"), (0.5, 0.3, 0.2), (0.35, 0.6), (0.4, 0.7), (10.0, 20.0)
    ),
    "stone": Family(("speckle", "mottled"), (0.6, 0.4), (0.0, 0.2), (0.2, 0.9), gloss=(0.1, 0.4)),
}
FAMILY_NAMES = tuple(FAMILIES)

_CASE = {0: ("wood", "paint")}
CLASS_FAMILIES: dict[str, dict[int, tuple[str, ...]]] = {  # class -> material slot -> families
    "bathtub": {0: ("ceramic",), 1: ("metal",)},
    "bed": {0: ("wood", "fabric"), 2: ("bedding",), 3: ("bedding", "fabric")},
    "bookshelf": _CASE,
    "box": {0: ("cardboard", "plastic")},
    "chair": {0: ("wood", "fabric", "plastic", "metal"), 2: ("fabric", "wood")},
    "counter": {0: ("stone", "paint", "wood")},
    "desk": _CASE,
    "door": _CASE,
    "dresser": _CASE,
    "garbage bin": {0: ("metal", "plastic")},
    "lamp": {0: ("metal", "paint"), 1: ("metal",), 2: ("fabric", "bedding")},
    "monitor": {0: ("screen",), 2: ("screen",)},
    "night stand": _CASE,
    "pillow": {0: ("fabric", "bedding")},
    "sink": {0: ("ceramic",)},
    "sofa": {0: ("fabric",), 2: ("fabric",)},
    "table": {0: ("wood", "paint", "stone")},
    "television": {0: ("screen",), 2: ("screen",)},
    "toilet": {0: ("ceramic",), 1: ("ceramic", "plastic")},
}


def draw_family_materials(rng: np.random.Generator, per_family: int) -> Materials:
    """``per_family`` materials of every family, family by family in FAMILY_NAMES order."""
    drawn = []
    for family in FAMILIES.values():
        for _ in range(per_family):
            kind = str(rng.choice(family.kinds, p=family.weights))
            texture, tile = material_texture(rng, kind, family.sat, family.val, family.hue)
            drawn.append((texture, tile, float(rng.uniform(*family.gloss)), kind))
    return stack_materials(drawn)


def typical_slots(
    rng: np.random.Generator, cls: str | None, slots: np.ndarray, first: int, per_family: int, share: float
) -> np.ndarray:
    """A model's material per slot: ``slots`` (palette picks), with probability ``share`` the
    slots its class names in CLASS_FAMILIES replaced by a material of one of their families
    (``first``: the index of the first family material in the frame's bank)."""
    named = CLASS_FAMILIES.get(cls)  # None for clutter (cls None)
    if named is None or rng.random() >= share:
        return slots
    out = slots.copy()
    for slot, families in named.items():
        family = FAMILY_NAMES.index(str(rng.choice(families)))
        out[slot] = first + family * per_family + int(rng.integers(per_family))
    return out
