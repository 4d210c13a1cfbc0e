"""Objects of no class that real rooms are full of, and near-miss shapes of the classes.

A detector trained only on rooms of the 19 classes learns that every box-like thing is one of
them: real frames then get office cabinets called bookshelves, partitions called sofas, bottles
called monitors. These builders give the "none of them" side: storage that is no bookshelf or
dresser (open shelving, filing and low cabinets), cubicle partitions, radiators, wall panels and
whiteboards, floor plants, bags and suitcases, small electronics, and near misses of classes
(stools beside chairs, benches beside sofas, poufs, coat stands, floor fans). All are
``Furniture`` with class None in the object frame of ``a3d.synth.parts``; wall-hung items have
their back at z = 0 and their base at h = 0 (the caller sets the height).
"""

from __future__ import annotations

import math

import numpy as np

from a3d.synth.furniture import Rng, drawer_front, uniform
from a3d.synth.parts import Furniture, Part, Surface, box, cbox, cyl


def _slot(rng: Rng) -> int:
    return int(rng.integers(0, 4))


# ----------------------------------------------------------------------------- storage that is no class


def shelving(rng: Rng) -> Furniture:
    """An open shelving unit: four thin posts and 3-6 bare shelves (no sides, no books)."""
    w, d, h = uniform(rng, 0.6, 1.5), uniform(rng, 0.3, 0.55), uniform(rng, 0.8, 2.0)
    t, post = uniform(rng, 0.015, 0.03), uniform(rng, 0.02, 0.04)
    parts = [
        cbox(post, post, 0, h, sx * (w - post) / 2, sz * (d - post) / 2, 1)
        for sx in (-1, 1)
        for sz in (-1, 1)
    ]
    for shelf_h in np.linspace(0.08, h - t, int(rng.integers(3, 7))):
        parts.append(cbox(w, d, float(shelf_h), float(shelf_h) + t, slot=0))
    return Furniture(None, parts, [Surface(-w / 2 + 0.03, w / 2 - 0.03, -d / 2 + 0.03, d / 2 - 0.03, h)])


def filing_cabinet(rng: Rng) -> Furniture:
    """A narrow metal cabinet of 2-4 stacked drawers, or a low two-door office cabinet."""
    if rng.random() < 0.5:
        w, d, h = uniform(rng, 0.4, 0.5), uniform(rng, 0.45, 0.65), uniform(rng, 0.7, 1.35)
        rows, cols = int(rng.integers(2, 5)), 1
    else:
        w, d, h = uniform(rng, 0.8, 1.6), uniform(rng, 0.4, 0.5), uniform(rng, 0.7, 1.2)
        rows, cols = 1, 2
    parts = [box(-w / 2, w / 2, 0, h, -d / 2, d / 2 - 0.02, 0)]
    xs, hs = np.linspace(-w / 2, w / 2, cols + 1), np.linspace(0.0, h, rows + 1)
    for i in range(cols):
        for j in range(rows):
            parts += drawer_front(rng, xs[i], xs[i + 1], hs[j], hs[j + 1], d / 2 - 0.02, 2, 1)
    return Furniture(None, parts, [Surface(-w / 2 + 0.03, w / 2 - 0.03, -d / 2 + 0.03, d / 2 - 0.05, h)])


def partition(rng: Rng) -> Furniture:
    """A cubicle partition or room divider: a thin upholstered panel on two feet, along x."""
    w, h, t = uniform(rng, 0.9, 1.8), uniform(rng, 1.1, 1.8), uniform(rng, 0.03, 0.07)
    parts = [box(-w / 2, w / 2, 0.04, h, -t / 2, t / 2, 0)]
    parts += [cbox(0.06, uniform(rng, 0.3, 0.5), 0, 0.04, sx * (w / 2 - 0.1), slot=1) for sx in (-1, 1)]
    parts.append(box(-w / 2, w / 2, h - 0.03, h, -t / 2 - 0.005, t / 2 + 0.005, 1))  # top rail
    return Furniture(None, parts)


# ----------------------------------------------------------------------------- on the walls


def radiator(rng: Rng) -> Furniture:
    """A panel radiator: a row of vertical fins on a back plate (hung: base at h = 0)."""
    w, h, d = uniform(rng, 0.5, 1.6), uniform(rng, 0.35, 0.7), uniform(rng, 0.06, 0.12)
    n = max(4, round(w / uniform(rng, 0.05, 0.09)))
    parts = [box(-w / 2, w / 2, 0, h, 0.02, 0.03, 0)]
    pitch = w / n
    parts += [box(-w / 2 + k * pitch, -w / 2 + (k + 0.6) * pitch, 0, h, 0.03, d, 0) for k in range(n)]
    return Furniture(None, parts)


def wall_panel(rng: Rng) -> Furniture:
    """A whiteboard, notice board or flat wall panel (hung: back at z = 0, base at h = 0)."""
    w, h = uniform(rng, 0.6, 2.0), uniform(rng, 0.5, 1.2)
    parts = [box(-w / 2, w / 2, 0, h, 0, uniform(rng, 0.01, 0.025), 0)]
    if rng.random() < 0.6:  # a frame and a pen tray
        f = uniform(rng, 0.015, 0.03)
        parts += [box(-w / 2, w / 2, 0, f, 0, 0.03, 1), box(-w / 2, w / 2, h - f, h, 0, 0.03, 1)]
        parts.append(box(-w / 3, w / 3, -0.03, 0.0, 0, 0.07, 1))
    return Furniture(None, parts)


# ----------------------------------------------------------------------------- on the floor


def floor_plant(rng: Rng) -> Furniture:
    """A potted plant: a pot and a stack of foliage cylinders of varying width."""
    r, ph = uniform(rng, 0.12, 0.25), uniform(rng, 0.2, 0.45)
    parts = [cyl(0, 0, r, 0, ph, 0), cyl(0, 0, r * 0.7, ph, ph + 0.1, 1)]
    h, top = ph + 0.05, ph + uniform(rng, 0.4, 1.4)
    while h < top:
        dh = uniform(rng, 0.1, 0.25)
        rx = r * uniform(rng, 0.8, 2.2)
        parts.append(
            cyl(
                uniform(rng, -0.05, 0.05),
                uniform(rng, -0.05, 0.05),
                rx,
                h,
                h + dh,
                3,
                rz=rx * uniform(rng, 0.6, 1.2),
            )
        )
        h += dh * 0.8
    return Furniture(None, parts)


def bag(rng: Rng) -> Furniture:
    """A backpack, handbag, shopping bag, crisp bag or suitcase: soft boxes of bag sizes."""
    kind = rng.choice(["backpack", "handbag", "shopping", "crisps", "suitcase"])
    s = _slot(rng)
    if kind == "suitcase":
        w, d, h = uniform(rng, 0.35, 0.5), uniform(rng, 0.2, 0.3), uniform(rng, 0.5, 0.75)
        return Furniture(
            None,
            [
                cbox(w, d, 0.04, h, slot=s),
                cbox(0.2, 0.03, h, h + 0.15, slot=1),
                *[cyl(sx * (w / 2 - 0.04), 0, 0.02, 0, 0.04, 1) for sx in (-1, 1)],
            ],
        )
    w, d, h = {
        "backpack": (uniform(rng, 0.28, 0.36), uniform(rng, 0.15, 0.25), uniform(rng, 0.35, 0.5)),
        "handbag": (uniform(rng, 0.25, 0.4), uniform(rng, 0.1, 0.18), uniform(rng, 0.2, 0.3)),
        "shopping": (uniform(rng, 0.3, 0.45), uniform(rng, 0.12, 0.2), uniform(rng, 0.3, 0.45)),
        "crisps": (uniform(rng, 0.15, 0.3), uniform(rng, 0.05, 0.1), uniform(rng, 0.2, 0.35)),
    }[str(kind)]
    parts = [cbox(w, d, 0, h * 0.85, slot=s), cbox(w * 0.9, d * 0.7, h * 0.85, h, slot=s)]
    if kind in ("handbag", "shopping"):
        parts.append(box(-w / 4, w / 4, h, h + 0.12, -0.01, 0.01, 1))  # handle
    if kind == "backpack":
        parts.append(cbox(w * 0.7, 0.06, 0.05, h * 0.5, z=d / 2 + 0.03, slot=_slot(rng)))  # front pocket
    return Furniture(None, parts)


def coat_stand(rng: Rng) -> Furniture:
    """A coat stand with hanging clothes, or a floor fan: tall thin things that are no lamp."""
    if rng.random() < 0.5:
        h = uniform(rng, 1.6, 1.9)
        parts = [cyl(0, 0, uniform(rng, 0.15, 0.25), 0, 0.03, 1), cyl(0, 0, 0.02, 0, h, 1)]
        for _ in range(int(rng.integers(1, 4))):  # coats
            a = uniform(rng, 0, 2 * math.pi)
            parts.append(
                Part(
                    0,
                    (0.12 * math.sin(a), h - 0.45, 0.12 * math.cos(a)),
                    (uniform(rng, 0.15, 0.25), 0.35, 0.06),
                    a,
                    _slot(rng),
                )
            )
        return Furniture(None, parts)
    h, r = uniform(rng, 0.9, 1.4), uniform(rng, 0.18, 0.28)
    return Furniture(
        None,
        [cyl(0, 0, 0.18, 0, 0.04, 1), cyl(0, 0, 0.015, 0, h - r, 1), cyl(0, 0, r, h - 2 * r, h, 0, rz=0.06)],
    )


# ----------------------------------------------------------------------------- near misses of classes


def stool(rng: Rng) -> Furniture:
    """A backless stool (low or bar height) on 3-4 legs or a column: a near miss of a chair."""
    r, h = uniform(rng, 0.15, 0.22), uniform(rng, 0.42, 0.8)
    parts = [cyl(0, 0, r, h - uniform(rng, 0.03, 0.06), h, _slot(rng))]
    if rng.random() < 0.35:
        parts += [cyl(0, 0, 0.03, 0.03, h - 0.03, 1), cyl(0, 0, r * 1.1, 0, 0.03, 1)]
    else:
        n = int(rng.choice([3, 4]))
        for k in range(n):
            a = 2 * math.pi * k / n
            parts.append(cyl(0.75 * r * math.sin(a), 0.75 * r * math.cos(a), 0.018, 0, h - 0.03, 1))
        if h > 0.6:  # foot ring
            parts.append(cyl(0, 0, 0.8 * r, h * 0.35, h * 0.35 + 0.02, 1))
    return Furniture(None, parts)


def bench(rng: Rng) -> Furniture:
    """A backless bench or a long ottoman: a near miss of a sofa (long seat, no back, no arms)."""
    w, d, h = uniform(rng, 0.9, 1.8), uniform(rng, 0.3, 0.5), uniform(rng, 0.4, 0.48)
    if rng.random() < 0.5:  # upholstered block
        return Furniture(
            None,
            [cbox(w, d, 0.05, h, slot=_slot(rng)), cbox(w - 0.1, d - 0.06, 0, 0.05, slot=1)],
            [Surface(-w / 2 + 0.05, w / 2 - 0.05, -d / 2 + 0.05, d / 2 - 0.05, h)],
        )
    t = uniform(rng, 0.03, 0.06)
    parts = [cbox(w, d, h - t, h, slot=_slot(rng))]
    parts += [
        box(sx * w / 2 - 0.05, sx * w / 2 + 0.05, 0, h - t, -d / 2 + 0.02, d / 2 - 0.02, 1)
        for sx in (-1, 0.8)
    ]
    return Furniture(None, parts, [Surface(-w / 2 + 0.05, w / 2 - 0.05, -d / 2 + 0.05, d / 2 - 0.05, h)])


def pouf(rng: Rng) -> Furniture:
    """A round or square pouf: a fabric block on the floor, a near miss of pillow and sofa."""
    h = uniform(rng, 0.3, 0.45)
    if rng.random() < 0.5:
        return Furniture(None, [cyl(0, 0, uniform(rng, 0.2, 0.35), 0, h, _slot(rng))])
    s = uniform(rng, 0.4, 0.6)
    return Furniture(None, [cbox(s, s, 0, h, slot=_slot(rng))])


# ----------------------------------------------------------------------------- on tables, desks and shelves


def electronics(rng: Rng) -> Furniture:
    """A laptop, speaker, router, printer, keyboard, desk phone or globe."""
    kind = rng.choice(["laptop", "speaker", "router", "printer", "keyboard", "phone", "globe"])
    if kind == "laptop":
        w, d = uniform(rng, 0.3, 0.38), uniform(rng, 0.21, 0.26)
        return Furniture(
            None,
            [
                cbox(w, d, 0, 0.02, slot=1),
                box(-w / 2, w / 2, 0.02, 0.02 + d * 0.95, -d / 2, -d / 2 + 0.008, _slot(rng)),
            ],
        )
    if kind == "speaker":
        w, h = uniform(rng, 0.12, 0.25), uniform(rng, 0.18, 0.4)
        return Furniture(
            None,
            [
                cbox(w, uniform(rng, 0.12, 0.25), 0, h, slot=_slot(rng)),
                cyl(0, 0.0, w * 0.35, h * 0.3, h * 0.3 + 0.01, 1),
            ],
        )
    if kind == "router":
        w = uniform(rng, 0.15, 0.25)
        parts = [cbox(w, uniform(rng, 0.1, 0.16), 0, 0.035, slot=_slot(rng))]
        parts += [cyl(sx * w * 0.4, -0.04, 0.006, 0.03, 0.2, 1) for sx in (-1, 1)]
        return Furniture(None, parts)
    if kind == "printer":
        w, d, h = uniform(rng, 0.35, 0.5), uniform(rng, 0.3, 0.45), uniform(rng, 0.15, 0.3)
        return Furniture(
            None,
            [
                cbox(w, d, 0, h, slot=_slot(rng)),
                cbox(w * 0.7, 0.12, h * 0.3, h * 0.35, z=d / 2 + 0.06, slot=1),
            ],
        )
    if kind == "keyboard":
        return Furniture(
            None, [cbox(uniform(rng, 0.3, 0.45), uniform(rng, 0.12, 0.16), 0, 0.025, slot=_slot(rng))]
        )
    if kind == "phone":
        return Furniture(
            None, [cbox(0.2, 0.18, 0, 0.06, slot=_slot(rng)), cbox(0.05, 0.2, 0.06, 0.09, x=-0.06, slot=1)]
        )
    r = uniform(rng, 0.1, 0.16)  # globe: a stepped sphere on a stand
    parts = [cyl(0, 0, r * 0.7, 0, 0.02, 1), cyl(0, 0, 0.01, 0.02, 0.08, 1)]
    for k, f in enumerate((0.6, 0.92, 1.0, 0.92, 0.6)):
        parts.append(cyl(0, 0, r * f, 0.08 + k * 0.4 * r, 0.08 + (k + 1) * 0.4 * r, 0))
    return Furniture(None, parts)


def bottle(rng: Rng) -> Furniture:
    """A bottle, can or jar (tabletop clutter)."""
    r, h = uniform(rng, 0.03, 0.055), uniform(rng, 0.1, 0.33)
    if rng.random() < 0.6:
        return Furniture(
            None, [cyl(0, 0, r, 0, h * 0.7, _slot(rng)), cyl(0, 0, r * 0.4, h * 0.7, h, _slot(rng))]
        )
    return Furniture(None, [cyl(0, 0, r, 0, h * 0.5, _slot(rng))])
