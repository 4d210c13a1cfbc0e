"""Unannotated clutter: pictures, windows, rugs, cabinets and small tabletop items.

They are no class of a3d (never annotated), but they occlude, cast shadows and give the
detector hard negatives, as real rooms do. Same object frame and material slots as
``a3d.synth.furniture``; wall-hung items have their back at z = 0.
"""

from __future__ import annotations

import itertools

import numpy as np

from a3d.synth.furniture import Rng, drawer_front, uniform
from a3d.synth.parts import Furniture, box, cbox, cyl


def picture(rng: Rng) -> Furniture:
    """A framed picture (hung on a wall: back at z = 0)."""
    w, h, f = uniform(rng, 0.25, 1.0), uniform(rng, 0.2, 0.8), uniform(rng, 0.015, 0.05)
    return Furniture(
        None, [box(-w / 2, w / 2, 0, h, 0, 0.02, 1), box(-w / 2 + f, w / 2 - f, f, h - f, 0.02, 0.024, 2)]
    )


def window(rng: Rng) -> Furniture:
    """A window on a wall: frame bars, glass pane and sill (back at z = 0)."""
    w, h, f = uniform(rng, 0.6, 1.8), uniform(rng, 0.8, 1.4), uniform(rng, 0.04, 0.08)
    parts = [box(-w / 2 + f, w / 2 - f, f, h - f, 0, 0.005, 3)]
    parts += [
        box(-w / 2, w / 2, 0, f, 0, 0.04, 1),
        box(-w / 2, w / 2, h - f, h, 0, 0.04, 1),
        box(-w / 2, -w / 2 + f, 0, h, 0, 0.04, 1),
        box(w / 2 - f, w / 2, 0, h, 0, 0.04, 1),
    ]
    if w > 1.0:
        parts.append(box(-f / 3, f / 3, 0, h, 0, 0.03, 1))
    parts.append(box(-w / 2 - 0.05, w / 2 + 0.05, -0.03, 0.0, 0, uniform(rng, 0.08, 0.2), 1))
    return Furniture(None, parts, glow=0)


def rug(rng: Rng) -> Furniture:
    w, d = uniform(rng, 1.0, 2.5), uniform(rng, 0.8, 2.0)
    return Furniture(None, [cbox(w, d, 0, 0.004, slot=int(rng.integers(0, 4)))], collides=False)


def cabinet(rng: Rng, wall_hung: bool = False) -> Furniture:
    """A wardrobe, or a kitchen wall cabinet (hung: hung items have their base at h = 0 too)."""
    w = uniform(rng, 0.6, 1.5)
    d, h = (
        (uniform(rng, 0.3, 0.38), uniform(rng, 0.6, 0.9))
        if wall_hung
        else (uniform(rng, 0.5, 0.65), uniform(rng, 1.6, 2.1))
    )
    n = max(1, round(w / 0.5))
    parts = [box(-w / 2, w / 2, 0, h, -d / 2, d / 2 - 0.02, 0)]
    xs = np.linspace(-w / 2, w / 2, n + 1)
    for a, b in itertools.pairwise(xs):
        parts += drawer_front(rng, float(a), float(b), 0.0, h, d / 2 - 0.02, 2, 1)
    return Furniture(None, parts)


def small_item(rng: Rng) -> Furniture:
    """Cup, bottle, vase, book stack or potted plant: tabletop clutter that is no annotated class."""
    kind = rng.choice(["cup", "bottle", "vase", "books", "plant"])
    if kind == "cup":
        r = uniform(rng, 0.03, 0.05)
        return Furniture(None, [cyl(0, 0, r, 0, uniform(rng, 0.07, 0.12), int(rng.integers(0, 4)))])
    if kind == "bottle":
        r, h = uniform(rng, 0.03, 0.05), uniform(rng, 0.15, 0.3)
        return Furniture(None, [cyl(0, 0, r, 0, h * 0.7, 0), cyl(0, 0, r * 0.35, h * 0.7, h, 1)])
    if kind == "vase":
        r, h = uniform(rng, 0.04, 0.1), uniform(rng, 0.15, 0.4)
        return Furniture(None, [cyl(0, 0, r, 0, h * 0.6, 0), cyl(0, 0, r * 0.6, h * 0.6, h, 0)])
    if kind == "plant":
        r = uniform(rng, 0.06, 0.14)
        return Furniture(
            None, [cyl(0, 0, r, 0, r * 1.5, 0), cyl(0, 0, r * 1.6, r * 1.5, r * 3.5, 3, rz=r * 1.3)]
        )
    parts, h = [], 0.0
    for _ in range(int(rng.integers(1, 5))):
        t = uniform(rng, 0.015, 0.05)
        parts.append(
            cbox(uniform(rng, 0.15, 0.3), uniform(rng, 0.12, 0.22), h, h + t, slot=int(rng.integers(0, 4)))
        )
        h += t
    return Furniture(None, parts)
