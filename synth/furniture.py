"""Multi-part models of the 19 classes (and of unannotated clutter), with metric size priors.

Each builder draws its style and sizes from ``rng`` (sizes in metres, ranges after typical
furniture dimensions and NYUv2 box statistics) and returns a ``Furniture`` in the object frame
of ``a3d.synth.parts`` (x lateral, z to the front, h up, origin at the middle of the base).
Wall-standing objects have their back at the lowest z. Parts name a material *slot* (0 main,
1 secondary, 2 and 3 extra); the materials themselves are drawn later, independent of class
unless class-typical appearance is asked for (``a3d.synth.appearance``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np

from a3d.synth.parts import BOX, Furniture, Part, Surface, box, cbox, cyl

Rng = np.random.Generator


def uniform(rng: Rng, lo: float, hi: float) -> float:
    """A float drawn uniformly from [lo, hi)."""
    return float(rng.uniform(lo, hi))


def _legs(
    rng: Rng, w: float, d: float, h: float, inset: float, t: float, slot: int, h0: float = 0.0
) -> list[Part]:
    """Four legs of thickness t under a w x d top, from h0 to h, round or square at random."""
    round_legs = rng.random() < 0.4
    xs, zs = w / 2 - inset - t / 2, d / 2 - inset - t / 2
    out = []
    for sx in (-1, 1):
        for sz in (-1, 1):
            if round_legs:
                out.append(cyl(sx * xs, sz * zs, t / 2, h0, h, slot))
            else:
                out.append(cbox(t, t, h0, h, sx * xs, sz * zs, slot))
    return out


def _top_surface(w: float, d: float, h: float, inset: float = 0.03) -> Surface:
    return Surface(-w / 2 + inset, w / 2 - inset, -d / 2 + inset, d / 2 - inset, h)


def drawer_front(
    rng: Rng, x0: float, x1: float, h0: float, h1: float, z: float, slot: int, handle_slot: int
) -> list[Part]:
    """A drawer or cabinet door on the front plane z: a slightly proud panel and a handle."""
    gap, proud = 0.004, uniform(rng, 0.008, 0.02)
    parts = [box(x0 + gap, x1 - gap, h0 + gap, h1 - gap, z, z + proud, slot)]
    hw = min(uniform(rng, 0.06, 0.16), (x1 - x0) * 0.6)
    hc = h1 - min(0.06, (h1 - h0) / 2) if h1 - h0 > 0.3 else (h0 + h1) / 2
    if rng.random() < 0.5:
        parts.append(cbox(hw, 0.025, hc - 0.008, hc + 0.008, (x0 + x1) / 2, z + proud + 0.0125, handle_slot))
    else:
        parts.append(
            cyl((x0 + x1) / 2, z + proud + 0.012, 0.013, hc - 0.012, hc + 0.012, handle_slot, rz=0.012)
        )
    return parts


# ----------------------------------------------------------------------------- tables and desks


def table(rng: Rng, style: str | None = None) -> Furniture:
    """Dining, coffee, round pedestal or side table: a top on legs (apron or shelf optional)."""
    style = style or str(rng.choice(["dining", "coffee", "round", "side"], p=[0.45, 0.25, 0.15, 0.15]))
    t = uniform(rng, 0.025, 0.05)
    if style == "round":
        r, h = uniform(rng, 0.35, 0.6), uniform(rng, 0.70, 0.76)
        parts = [cyl(0, 0, r, h - t, h, 0), cyl(0, 0, uniform(rng, 0.03, 0.07), 0.03, h - t, 1)]
        parts.append(cyl(0, 0, uniform(rng, 0.2, 0.75 * r), 0, 0.03, 1))
        s = r / math.sqrt(2)
        return Furniture("table", parts, [Surface(-s, s, -s, s, h)])
    if style == "dining":
        w = uniform(rng, 0.9, 1.9)
        d, h = uniform(rng, 0.6, min(1.0, w)), uniform(rng, 0.70, 0.78)
    elif style == "coffee":
        w = uniform(rng, 0.7, 1.3)
        d, h = uniform(rng, 0.4, min(0.75, w)), uniform(rng, 0.35, 0.5)
    else:
        w = uniform(rng, 0.4, 0.65)
        d, h = uniform(rng, 0.4, w), uniform(rng, 0.45, 0.7)
    lt, inset = uniform(rng, 0.035, 0.08), uniform(rng, 0.0, 0.06)
    parts = [cbox(w, d, h - t, h, slot=0), *_legs(rng, w, d, h - t, inset, lt, 1)]
    if rng.random() < 0.5 and h > 0.6:  # apron boards under the top
        ah = uniform(rng, 0.06, 0.12)
        parts.append(cbox(w - 2 * (inset + lt * 0.3), d - 2 * (inset + lt * 0.3), h - t - ah, h - t, slot=0))
    if style == "coffee" and rng.random() < 0.5:  # lower shelf
        sh = uniform(rng, 0.08, 0.15)
        parts.append(cbox(w - 2 * inset, d - 2 * inset, sh, sh + 0.02, slot=0))
    return Furniture("table", parts, [_top_surface(w, d, h)])


def desk(rng: Rng) -> Furniture:
    """A desk top on legs, side panels or a drawer pedestal, with an optional modesty panel."""
    w, d, h, t = (
        uniform(rng, 1.0, 1.8),
        uniform(rng, 0.55, 0.8),
        uniform(rng, 0.71, 0.77),
        uniform(rng, 0.02, 0.04),
    )
    parts = [cbox(w, d, h - t, h, slot=0)]
    style = rng.choice(["legs", "panels", "pedestal"])
    pt = uniform(rng, 0.02, 0.04)
    if style == "legs":
        parts += _legs(rng, w, d, h - t, uniform(rng, 0.0, 0.04), uniform(rng, 0.035, 0.06), 1)
    elif style == "panels":
        parts += [
            box(-w / 2, -w / 2 + pt, 0, h - t, -d / 2, d / 2, 0),
            box(w / 2 - pt, w / 2, 0, h - t, -d / 2, d / 2, 0),
        ]
    else:
        pw = uniform(rng, 0.35, 0.45)
        side = rng.choice([-1.0, 1.0])
        x0, x1 = (w / 2 - pw, w / 2) if side > 0 else (-w / 2, -w / 2 + pw)
        parts.append(box(x0, x1, 0.0, h - t, -d / 2, d / 2 - 0.02, 0))
        n = int(rng.integers(2, 5))
        edges = np.linspace(0.03, h - t, n + 1)
        for a, b in itertools.pairwise(edges):
            parts += drawer_front(rng, x0, x1, float(a), float(b), d / 2 - 0.02, 2, 1)
        xo = -w / 2 + pt if side > 0 else w / 2 - pt
        parts.append(box(min(xo, xo - side * pt), max(xo, xo - side * pt), 0, h - t, -d / 2, d / 2, 0))
    if rng.random() < 0.5:
        parts.append(
            box(
                -w / 2 + pt,
                w / 2 - pt,
                h * uniform(rng, 0.3, 0.6),
                h - t,
                -d / 2 + 0.02,
                -d / 2 + 0.02 + pt,
                0,
            )
        )
    return Furniture("desk", parts, [_top_surface(w, d, h)])


# ----------------------------------------------------------------------------- seating


def chair(rng: Rng, style: str | None = None) -> Furniture:
    """A four-legged chair, an office chair on a star base, or an upholstered armchair."""
    style = style or str(rng.choice(["legs", "office", "armchair"], p=[0.6, 0.28, 0.12]))
    if style == "armchair":
        w, d = uniform(rng, 0.7, 0.95), uniform(rng, 0.7, 0.9)
        sh, bh, ah, aw = (
            uniform(rng, 0.38, 0.45),
            uniform(rng, 0.75, 1.0),
            uniform(rng, 0.55, 0.68),
            uniform(rng, 0.1, 0.2),
        )
        bt, lh = uniform(rng, 0.12, 0.2), uniform(rng, 0.0, 0.12)
        parts = [cbox(w - 2 * aw, d - bt, lh, sh - 0.1, z=bt / 2, slot=0)]
        parts.append(cbox(w - 2 * aw, d - bt - 0.02, sh - 0.1, sh, z=bt / 2 + 0.01, slot=2))
        parts.append(box(-w / 2, w / 2, lh, bh, -d / 2, -d / 2 + bt, 0))
        parts += [
            box(-w / 2, -w / 2 + aw, lh, ah, -d / 2, d / 2, 0),
            box(w / 2 - aw, w / 2, lh, ah, -d / 2, d / 2, 0),
        ]
        if lh > 0.02:
            parts += _legs(rng, w, d, lh, 0.03, 0.04, 1)
        return Furniture("chair", parts)
    w, d = uniform(rng, 0.4, 0.52), uniform(rng, 0.4, 0.52)
    sh, st = uniform(rng, 0.42, 0.49), uniform(rng, 0.025, 0.07)
    back = uniform(rng, 0.32, 0.55)
    bt = uniform(rng, 0.02, 0.05)
    if style == "office":
        parts = [cbox(w, d, sh - st, sh, slot=2)]
        parts.append(box(-w / 2 + 0.02, w / 2 - 0.02, sh + 0.04, sh + 0.04 + back, -d / 2 - bt, -d / 2, 2))
        parts.append(cbox(0.05, 0.02, sh - st - 0.02, sh + 0.06, z=-d / 2 - bt / 2, slot=1))  # back spine
        parts.append(cyl(0, 0, uniform(rng, 0.02, 0.035), 0.09, sh - st, 1))
        parts.append(cyl(0, 0, 0.045, 0.07, 0.2, 1))
        arm_r, yaw0 = uniform(rng, 0.26, 0.33), uniform(rng, 0, 2 * math.pi / 5)
        for k in range(5):
            a = yaw0 + 2 * math.pi * k / 5
            c = (arm_r / 2 * math.sin(a), 0.075, arm_r / 2 * math.cos(a))
            parts.append(Part(BOX, c, (0.018, 0.02, arm_r / 2), a, 1))
            parts.append(cyl(arm_r * math.sin(a), arm_r * math.cos(a), 0.025, 0.0, 0.05, 1))
        if rng.random() < 0.5:  # arm rests
            for sx in (-1, 1):
                parts.append(
                    box(sx * w / 2 - 0.025, sx * w / 2 + 0.025, sh + 0.18, sh + 0.21, -d / 3, d / 3, 1)
                )
                parts.append(box(sx * w / 2 - 0.015, sx * w / 2 + 0.015, sh - st, sh + 0.18, -0.03, 0.0, 1))
        return Furniture("chair", parts)
    lt = uniform(rng, 0.025, 0.045)
    parts = [cbox(w, d, sh - st, sh, slot=0 if rng.random() < 0.6 else 2)]
    parts += _legs(rng, w, d, sh - st, 0.01, lt, 1)
    top = sh + back
    px = w / 2 - 0.01 - lt / 2  # back posts continue the back legs
    parts += [
        box(sx * px - lt / 2, sx * px + lt / 2, sh, top, -d / 2 + 0.01, -d / 2 + 0.01 + max(bt, lt), 1)
        for sx in (-1, 1)
    ]
    if rng.random() < 0.6:
        parts.append(
            box(
                -w / 2 + 0.01 + lt / 2,
                w / 2 - 0.01 - lt / 2,
                sh + back * uniform(rng, 0.15, 0.4),
                top - 0.01,
                -d / 2 + 0.015,
                -d / 2 + 0.01 + bt,
                0,
            )
        )
    else:  # slats
        for hh in np.linspace(sh + back * 0.35, top - 0.03, int(rng.integers(2, 4))):
            parts.append(
                box(
                    -w / 2 + 0.01,
                    w / 2 - 0.01,
                    float(hh) - 0.025,
                    float(hh) + 0.025,
                    -d / 2 + 0.015,
                    -d / 2 + bt,
                    0,
                )
            )
    if rng.random() < 0.3:  # side stretchers joining the front and back legs
        sh2, xs = uniform(rng, 0.1, 0.2), w / 2 - 0.01 - lt / 2
        parts += [cbox(lt * 0.6, d - 0.02 - lt, sh2, sh2 + 0.02, x=sx * xs, slot=1) for sx in (-1, 1)]
    return Furniture("chair", parts)


def sofa(rng: Rng) -> Furniture:
    """A two- or three-seater: base, seat and back cushions, back frame, arms, optional legs."""
    n = int(rng.integers(2, 4))
    w = n * uniform(rng, 0.55, 0.7) + 2 * uniform(rng, 0.1, 0.25)
    d, sh = uniform(rng, 0.8, 1.0), uniform(rng, 0.38, 0.46)
    bh, ah, aw = uniform(rng, 0.75, 0.95), uniform(rng, 0.52, 0.68), uniform(rng, 0.1, 0.25)
    bt, lh, ct = uniform(rng, 0.14, 0.22), uniform(rng, 0.0, 0.12), uniform(rng, 0.1, 0.16)
    if lh < 0.03:
        lh = 0.0
    parts = [box(-w / 2 + aw, w / 2 - aw, lh, sh - ct, -d / 2 + bt, d / 2, 0)]
    parts.append(box(-w / 2, w / 2, lh, bh, -d / 2, -d / 2 + bt, 0))
    parts += [
        box(-w / 2, -w / 2 + aw, lh, ah, -d / 2, d / 2, 0),
        box(w / 2 - aw, w / 2, lh, ah, -d / 2, d / 2, 0),
    ]
    inner = np.linspace(-w / 2 + aw, w / 2 - aw, n + 1)
    ct2 = uniform(rng, 0.1, 0.17)
    for a, b in itertools.pairwise(inner):
        parts.append(box(float(a) + 0.005, float(b) - 0.005, sh - ct, sh, -d / 2 + bt + ct2, d / 2 - 0.01, 2))
        parts.append(
            box(
                float(a) + 0.01,
                float(b) - 0.01,
                sh,
                bh - uniform(rng, 0.02, 0.08),
                -d / 2 + bt,
                -d / 2 + bt + ct2,
                2,
            )
        )
    if lh > 0:
        parts += _legs(rng, w, d, lh, 0.04, 0.05, 1)
    seat = Surface(
        -w / 2 + aw + 0.05, w / 2 - aw - 0.05, -d / 2 + bt + ct2 + 0.01, -d / 2 + bt + ct2 + 0.3, sh
    )
    return Furniture("sofa", parts, [seat])


def bed(rng: Rng) -> Furniture:
    """Frame, mattress, headboard at the back (-z), optional footboard, legs and blanket."""
    w, length = (
        float(rng.choice([uniform(rng, 0.9, 1.1), uniform(rng, 1.35, 1.95)])),
        uniform(rng, 1.95, 2.15),
    )
    fh, mt = uniform(rng, 0.18, 0.35), uniform(rng, 0.15, 0.3)
    hb, ht = uniform(rng, 0.8, 1.3), uniform(rng, 0.04, 0.1)
    lh = uniform(rng, 0.05, 0.15) if rng.random() < 0.5 else 0.0
    top = fh + mt
    z0 = -length / 2
    parts = [box(-w / 2, w / 2, 0, hb, z0, z0 + ht, 0)]
    parts.append(box(-w / 2, w / 2, lh, fh, z0 + ht, length / 2, 0))
    parts.append(box(-w / 2 + 0.02, w / 2 - 0.02, fh, top, z0 + ht + 0.01, length / 2 - 0.02, 2))
    if lh > 0:
        parts += _legs(rng, w, length, lh, 0.02, 0.06, 1)
    if rng.random() < 0.4:
        parts.append(
            box(-w / 2, w / 2, 0, top + uniform(rng, 0.05, 0.3), length / 2 - ht, length / 2 + 0.01, 0)
        )
    pillow_end = z0 + ht + uniform(rng, 0.45, 0.7)
    if rng.random() < 0.7:  # blanket over the foot part, hanging over the sides
        hang = uniform(rng, 0.1, 0.25)
        parts.append(
            box(
                -w / 2 - 0.03,
                w / 2 + 0.03,
                max(top - hang, lh + 0.02),
                top + 0.03,
                pillow_end,
                length / 2 - 0.01,
                3,
            )
        )
    return Furniture(
        "bed", parts, [Surface(-w / 2 + 0.05, w / 2 - 0.05, z0 + ht + 0.02, pillow_end - 0.02, top)]
    )


def pillow(rng: Rng, upright: bool = False) -> Furniture:
    """A cushion: a puffy core on a thinner rim; lying flat, or upright (thin along z)."""
    w, l_, t = uniform(rng, 0.35, 0.7), uniform(rng, 0.3, 0.5), uniform(rng, 0.1, 0.2)
    if upright:
        w = min(w, 0.55)
        l_ = min(l_, w)
        parts = [
            box(-w / 2, w / 2, 0, l_, -t * 0.3, t * 0.3, 0),
            box(-w / 2 + 0.04, w / 2 - 0.04, 0.03, l_ - 0.04, -t / 2, t / 2, 0),
        ]
    else:
        parts = [
            box(-w / 2, w / 2, 0, t * 0.6, -l_ / 2, l_ / 2, 0),
            box(-w / 2 + 0.04, w / 2 - 0.04, 0, t, -l_ / 2 + 0.04, l_ / 2 - 0.04, 0),
        ]
    return Furniture("pillow", parts)


# ----------------------------------------------------------------------------- storage


def bookshelf(rng: Rng) -> Furniture:
    """Sides, top, plinth, optional back, shelves, and runs of books standing on them."""
    w, d, h, t = (
        uniform(rng, 0.6, 1.2),
        uniform(rng, 0.25, 0.4),
        uniform(rng, 0.8, 2.0),
        uniform(rng, 0.015, 0.03),
    )
    plinth = uniform(rng, 0.03, 0.1)
    parts = [box(-w / 2, -w / 2 + t, 0, h, -d / 2, d / 2, 0), box(w / 2 - t, w / 2, 0, h, -d / 2, d / 2, 0)]
    parts += [
        box(-w / 2 + t, w / 2 - t, h - t, h, -d / 2, d / 2, 0),
        box(-w / 2 + t, w / 2 - t, 0, plinth, -d / 2, d / 2, 0),
    ]
    if rng.random() < 0.75:
        parts.append(box(-w / 2 + t, w / 2 - t, plinth, h - t, -d / 2, -d / 2 + 0.01, 1))
    n = max(2, round((h - plinth) / uniform(rng, 0.28, 0.4)))
    levels = np.linspace(plinth, h - t, n + 1)
    for i, (a, b) in enumerate(itertools.pairwise(levels)):
        a, b = float(a), float(b)
        if i > 0:
            parts.append(box(-w / 2 + t, w / 2 - t, a - t / 2, a + t / 2, -d / 2 + 0.01, d / 2 - 0.01, 0))
        parts += _books(rng, -w / 2 + t, w / 2 - t, a + (t / 2 if i > 0 else 0.0), b - t, d)
    return Furniture("bookshelf", parts)


def _books(rng: Rng, x0: float, x1: float, h0: float, h_max: float, d: float) -> list[Part]:
    """Runs of books standing on a shelf between x0 and x1 (gaps between runs)."""
    parts, x = [], x0 + uniform(rng, 0.0, 0.1)
    room = h_max - h0
    while x < x1 - 0.03:
        if rng.random() < 0.3:
            x += uniform(rng, 0.05, 0.3)
            continue
        slot = int(rng.integers(2, 4))
        for _ in range(int(rng.integers(2, 8))):
            bw = uniform(rng, 0.02, 0.06)
            if x + bw > x1:
                break
            bh, bd = room * uniform(rng, 0.55, 0.95), min(uniform(rng, 0.15, 0.25), d - 0.03)
            front = d / 2 - uniform(rng, 0.005, 0.03)  # spines near the shelf's front edge
            parts.append(box(x, x + bw, h0, h0 + bh, front - bd, front, slot))
            x += bw + 0.002
    return parts


def _chest(rng: Rng, cls: str, w: float, d: float, h: float, rows: int, cols: int) -> Furniture:
    """Body, overhanging top, plinth or legs and a grid of drawers on the front (dresser, night stand)."""
    t = uniform(rng, 0.015, 0.04)
    base = uniform(rng, 0.03, 0.15)
    body_d = d - uniform(rng, 0.0, 0.03)
    parts = [cbox(w, d, h - t, h, slot=0)]
    parts.append(box(-w / 2 + 0.01, w / 2 - 0.01, base, h - t, -d / 2, -d / 2 + body_d - 0.02, 0))
    if rng.random() < 0.5:
        parts += _legs(rng, w - 0.02, body_d, base, 0.0, 0.04, 1)
    else:
        parts.append(box(-w / 2 + 0.03, w / 2 - 0.03, 0, base, -d / 2, -d / 2 + body_d - 0.05, 1))
    fz = -d / 2 + body_d - 0.02
    hs = np.linspace(base, h - t, rows + 1)
    xs = np.linspace(-w / 2 + 0.01, w / 2 - 0.01, cols + 1)
    open_shelf = cls == "night stand" and rows == 2 and rng.random() < 0.4
    for r in range(rows):
        for c in range(cols):
            if open_shelf and r == 0:
                continue
            parts += drawer_front(
                rng, float(xs[c]), float(xs[c + 1]), float(hs[r]), float(hs[r + 1]), fz, 2, 1
            )
    if open_shelf:  # the body is hollow below the drawer: its sides and back stay
        parts[1] = box(-w / 2 + 0.01, w / 2 - 0.01, float(hs[1]), h - t, -d / 2, fz, 0)
        parts += [
            box(-w / 2 + 0.01, -w / 2 + 0.03, base, float(hs[1]), -d / 2, fz, 0),
            box(w / 2 - 0.03, w / 2 - 0.01, base, float(hs[1]), -d / 2, fz, 0),
            box(-w / 2 + 0.03, w / 2 - 0.03, base, float(hs[1]), -d / 2, -d / 2 + 0.015, 0),
            box(-w / 2 + 0.03, w / 2 - 0.03, base, base + 0.02, -d / 2, fz, 0),
        ]
    return Furniture(cls, parts, [_top_surface(w, d, h)])


def dresser(rng: Rng) -> Furniture:
    w, h = uniform(rng, 0.7, 1.6), uniform(rng, 0.7, 1.3)
    return _chest(
        rng,
        "dresser",
        w,
        uniform(rng, 0.4, 0.55),
        h,
        int(np.clip(round(h / 0.22), 3, 6)),
        1 if w < 0.9 else int(rng.integers(1, 4)),
    )


def night_stand(rng: Rng) -> Furniture:
    return _chest(
        rng,
        "night stand",
        uniform(rng, 0.4, 0.6),
        uniform(rng, 0.35, 0.5),
        uniform(rng, 0.45, 0.7),
        int(rng.integers(1, 4)),
        1,
    )


def box_(rng: Rng) -> Furniture:
    """A carton: closed (with a lid seam or flaps) or open (hollow walls)."""
    w = uniform(rng, 0.2, 0.7)
    d, h = uniform(rng, 0.2, min(w, 0.6)), uniform(rng, 0.15, 0.6)
    if rng.random() < 0.25:
        t = uniform(rng, 0.004, 0.012)
        parts = [
            cbox(w, d, 0, t),
            box(-w / 2, -w / 2 + t, 0, h, -d / 2, d / 2),
            box(w / 2 - t, w / 2, 0, h, -d / 2, d / 2),
        ]
        parts += [
            box(-w / 2 + t, w / 2 - t, 0, h, -d / 2, -d / 2 + t),
            box(-w / 2 + t, w / 2 - t, 0, h, d / 2 - t, d / 2),
        ]
        return Furniture("box", parts)
    parts = [cbox(w, d, 0, h, slot=0)]
    if rng.random() < 0.4:
        parts.append(
            cbox(w + 0.01, d + 0.01, h - uniform(rng, 0.03, 0.08), h + 0.004, slot=int(rng.integers(0, 2)))
        )
    return Furniture("box", parts, [_top_surface(w, d, h + 0.004 * (len(parts) - 1), 0.02)])


def counter(
    rng: Rng,
    length: float,
    depth: float,
    height: float,
    hole: tuple[float, float, float, float] | None,
    basin_bottom: float,
) -> Furniture:
    """Kitchen or bathroom counter: toe kick, cabinet body, doors, top slab.

    ``hole = (x0, x1, z0, z1)`` is a sink opening in the top; the body under it is lowered to
    ``basin_bottom`` so that the sink basin hanging in the hole is not buried in a solid.
    """
    t, kick, rec, over = (
        uniform(rng, 0.02, 0.045),
        uniform(rng, 0.07, 0.12),
        uniform(rng, 0.04, 0.08),
        uniform(rng, 0.01, 0.04),
    )
    L, D, H = length, depth, height
    zf = D / 2 - over  # front plane of the body
    parts = [box(-L / 2, L / 2, 0, kick, -D / 2, zf - rec, 1)]
    if hole is None:
        parts += [
            box(-L / 2, L / 2, kick, H - t, -D / 2, zf, 0),
            box(-L / 2, L / 2, H - t, H, -D / 2, D / 2, 1),
        ]
    else:
        x0, x1, z0, z1 = hole
        low = basin_bottom - 0.01
        parts += [
            box(-L / 2, x0, kick, H - t, -D / 2, zf, 0),
            box(x1, L / 2, kick, H - t, -D / 2, zf, 0),
            box(x0, x1, kick, low, -D / 2, zf, 0),
            box(x0, x1, low, H - t, zf - 0.02, zf, 0),
            box(x0, x1, low, H - t, -D / 2, z0, 0),
        ]
        parts += [
            box(-L / 2, x0, H - t, H, -D / 2, D / 2, 1),
            box(x1, L / 2, H - t, H, -D / 2, D / 2, 1),
            box(x0, x1, H - t, H, -D / 2, z0, 1),
            box(x0, x1, H - t, H, z1, D / 2, 1),
        ]
    n = max(1, round(L / uniform(rng, 0.4, 0.6)))
    xs = np.linspace(-L / 2, L / 2, n + 1)
    drawers = rng.random() < 0.5
    for a, b in itertools.pairwise(xs):
        top_d = H - t - (0.17 if drawers else 0.0)
        parts += drawer_front(rng, float(a), float(b), kick, top_d, zf, 2, 3)
        if drawers:
            parts += drawer_front(rng, float(a), float(b), top_d, H - t, zf, 2, 3)
    surf = [Surface(-L / 2 + 0.03, L / 2 - 0.03, -D / 2 + 0.03, D / 2 - 0.03, H)]
    if hole is not None:
        surf = [
            Surface(-L / 2 + 0.03, hole[0] - 0.05, -D / 2 + 0.03, D / 2 - 0.03, H),
            Surface(hole[1] + 0.05, L / 2 - 0.03, -D / 2 + 0.03, D / 2 - 0.03, H),
        ]
    return Furniture("counter", parts, [s for s in surf if s.x1 - s.x0 > 0.15])


# ----------------------------------------------------------------------------- sinks, bathroom


def _basin(rng: Rng, w: float, d: float, depth: float, wall: float, h0: float) -> list[Part]:
    """A hollow rectangular basin: bottom and four walls, from height h0 up to h0 + depth."""
    h1 = h0 + depth
    return [
        box(-w / 2, w / 2, h0, h0 + wall, -d / 2, d / 2, 0),
        box(-w / 2, -w / 2 + wall, h0, h1, -d / 2, d / 2, 0),
        box(w / 2 - wall, w / 2, h0, h1, -d / 2, d / 2, 0),
        box(-w / 2 + wall, w / 2 - wall, h0, h1, -d / 2, -d / 2 + wall, 0),
        box(-w / 2 + wall, w / 2 - wall, h0, h1, d / 2 - wall, d / 2, 0),
    ]


def _faucet(rng: Rng, z_back: float, h0: float, reach: float) -> list[Part]:
    """Base, riser and spout of a tap standing at z_back on height h0, reaching forward."""
    r, rise = uniform(rng, 0.015, 0.03), uniform(rng, 0.1, 0.3)
    return [
        cyl(0, z_back, r * 1.4, h0, h0 + 0.03, 1),
        cyl(0, z_back, r, h0, h0 + rise, 1),
        box(-r * 0.8, r * 0.8, h0 + rise - 0.03, h0 + rise, z_back, z_back + reach, 1),
    ]


def counter_with_sink(rng: Rng, length: float) -> tuple[Furniture, Furniture, tuple[float, float, float]]:
    """A counter and the drop-in sink in it: (counter, sink, sink pose (x, z, base) in the counter frame)."""
    depth, height = uniform(rng, 0.55, 0.65), uniform(rng, 0.82, 0.94)
    sw = min(uniform(rng, 0.4, 0.8), length - 0.2)
    sd = min(uniform(rng, 0.32, 0.45), depth - 0.2)  # keeps the hole clear of the front doors and the tap
    basin = uniform(rng, 0.12, 0.22)
    sx = uniform(rng, -length / 2 + sw / 2 + 0.05, length / 2 - sw / 2 - 0.05)
    sz = uniform(rng, -0.02, 0.0)
    wall = 0.015
    rim = 0.012
    hole = (sx - sw / 2, sx + sw / 2, sz - sd / 2, sz + sd / 2)
    c = counter(rng, length, depth, height, hole, height - basin)
    parts = _basin(rng, sw, sd, basin + rim, wall, 0.0)
    parts += [
        box(-sw / 2 - 0.02, sw / 2 + 0.02, basin, basin + rim, -sd / 2 - 0.02, -sd / 2, 1),
        box(-sw / 2 - 0.02, sw / 2 + 0.02, basin, basin + rim, sd / 2, sd / 2 + 0.02, 1),
        box(-sw / 2 - 0.02, -sw / 2, basin, basin + rim, -sd / 2, sd / 2, 1),
        box(sw / 2, sw / 2 + 0.02, basin, basin + rim, -sd / 2, sd / 2, 1),
    ]
    back = -sd / 2 - 0.02 - 0.045
    if back > -depth / 2 + 0.02 - sz:
        parts += _faucet(rng, back, basin, sd * 0.4)
    return c, Furniture("sink", parts), (sx, sz, height - basin)


def pedestal_sink(rng: Rng) -> Furniture:
    """A wall-hung basin on a column (bathroom), with a tap at the back."""
    w, d, h = uniform(rng, 0.45, 0.65), uniform(rng, 0.35, 0.5), uniform(rng, 0.78, 0.9)
    depth = uniform(rng, 0.14, 0.2)
    parts = _basin(rng, w, d, depth, uniform(rng, 0.02, 0.05), h - depth)
    parts.append(cyl(0, -d / 2 + 0.12, uniform(rng, 0.08, 0.12), 0, h - depth, 0, rz=uniform(rng, 0.07, 0.1)))
    parts += _faucet(rng, -d / 2 + 0.035, h, d * 0.35)
    return Furniture("sink", parts)


def toilet(rng: Rng) -> Furniture:
    """Tank against the wall (-z), elliptic bowl on a pedestal, seat, optional raised lid."""
    tw, td = uniform(rng, 0.36, 0.5), uniform(rng, 0.15, 0.22)
    t0, t1 = uniform(rng, 0.38, 0.45), uniform(rng, 0.7, 0.85)
    rx, rz, bh = uniform(rng, 0.17, 0.2), uniform(rng, 0.21, 0.27), uniform(rng, 0.36, 0.41)
    zb = -0.35 + td + rz - 0.06
    parts = [
        box(-tw / 2, tw / 2, t0, t1, -0.35, -0.35 + td, 0),
        box(-tw / 2 - 0.01, tw / 2 + 0.01, t1, t1 + 0.025, -0.355, -0.345 + td, 0),
    ]
    parts += [
        cyl(0, zb, rx, 0.17, bh - 0.02, 0, rz=rz),
        cyl(0, zb - 0.03, rx * 0.6, 0, 0.17, 0, rz=rz * 0.65),
    ]
    parts.append(box(-0.09, 0.09, bh - 0.1, t0 + 0.02, -0.35 + td - 0.01, zb - rz + 0.1, 0))
    parts.append(cyl(0, zb, rx + 0.01, bh - 0.02, bh + 0.005, 1, rz=rz + 0.01))
    if rng.random() < 0.5:  # lid up against the tank
        parts.append(box(-rx, rx, bh, bh + 2 * rz - 0.05, -0.35 + td + 0.002, -0.35 + td + 0.025, 1))
    else:
        parts.append(cyl(0, zb + 0.005, rx + 0.005, bh + 0.005, bh + 0.025, 1, rz=rz + 0.005))
    return Furniture("toilet", parts)


def bathtub(rng: Rng) -> Furniture:
    """A hollow tub (walls, floor) on an apron, long side along x; a tap at one end."""
    L, W, H = uniform(rng, 1.4, 1.8), uniform(rng, 0.7, 0.85), uniform(rng, 0.45, 0.6)
    wall, floor = uniform(rng, 0.06, 0.12), uniform(rng, 0.08, 0.15)
    parts = [box(-L / 2, L / 2, 0, floor, -W / 2, W / 2, 0)]
    parts += [
        box(-L / 2, -L / 2 + wall, floor, H, -W / 2, W / 2, 0),
        box(L / 2 - wall, L / 2, floor, H, -W / 2, W / 2, 0),
        box(-L / 2 + wall, L / 2 - wall, floor, H, -W / 2, -W / 2 + wall, 0),
        box(-L / 2 + wall, L / 2 - wall, floor, H, W / 2 - wall, W / 2, 0),
    ]
    side = float(rng.choice([-1.0, 1.0]))
    parts.append(cyl(side * (L / 2 - wall / 2), -W / 2 + wall / 2, 0.02, H, H + 0.12, 1))
    parts.append(
        box(
            side * (L / 2 - wall / 2) - 0.015,
            side * (L / 2 - wall / 2) + 0.015,
            H + 0.09,
            H + 0.12,
            -W / 2 + wall / 2,
            -W / 2 + wall + 0.08,
            1,
        )
    )
    return Furniture("bathtub", parts)


def garbage_bin(rng: Rng) -> Furniture:
    """A round bin with a rim or lid, or a square open bin (hollow)."""
    h = uniform(rng, 0.3, 0.7)
    if rng.random() < 0.6:
        r = uniform(rng, 0.12, 0.22)
        parts = [cyl(0, 0, r, 0, h, 0)]
        parts.append(
            cyl(
                0,
                0,
                r + uniform(rng, 0.005, 0.015),
                h - 0.02,
                h + uniform(rng, 0.0, 0.04),
                int(rng.integers(0, 2)),
            )
        )
        return Furniture("garbage bin", parts)
    w, d = uniform(rng, 0.22, 0.4), uniform(rng, 0.2, 0.35)
    return Furniture("garbage bin", _basin(rng, w, d, h, 0.01, 0.0))


# ----------------------------------------------------------------------------- lamps, screens, doors


def lamp(rng: Rng, floor: bool | None = None) -> Furniture:
    """A table or floor lamp: base, stem, a shade of two stacked cylinders (a stepped cone)."""
    floor = bool(rng.random() < 0.35) if floor is None else floor
    if floor:
        br, stem, sr = uniform(rng, 0.12, 0.18), uniform(rng, 1.2, 1.6), uniform(rng, 0.15, 0.25)
    else:
        br, stem, sr = uniform(rng, 0.05, 0.1), uniform(rng, 0.15, 0.35), uniform(rng, 0.1, 0.2)
    sh = sr * uniform(rng, 0.9, 1.6)
    parts = [cyl(0, 0, br, 0, uniform(rng, 0.02, 0.05), 1)]
    if not floor and rng.random() < 0.5:  # a vase-like body
        parts.append(cyl(0, 0, br * uniform(rng, 0.6, 1.0), 0.02, stem * 0.7, 0))
    parts.append(cyl(0, 0, uniform(rng, 0.008, 0.02), 0, stem + sh * 0.5, 1))
    top_r = sr * uniform(rng, 0.6, 0.95)
    parts += [
        cyl(0, 0, sr, stem, stem + sh * 0.5, 2),
        cyl(0, 0, (sr + top_r) / 2, stem + sh * 0.5, stem + sh, 2),
    ]
    return Furniture("lamp", parts)


def monitor(rng: Rng) -> Furniture:
    """A flat screen on a neck and base plate; the screen faces +z."""
    w = uniform(rng, 0.4, 0.65)
    sh, st = w * uniform(rng, 0.55, 0.68), uniform(rng, 0.015, 0.04)
    lift = uniform(rng, 0.05, 0.15)
    bw, bd = uniform(rng, 0.16, 0.3), uniform(rng, 0.14, 0.22)
    face = -0.01 + st  # screen front plane; the neck stands behind the panel's back at z = -0.01
    parts = [cbox(bw, bd, 0, uniform(rng, 0.008, 0.02), slot=1)]
    parts.append(
        box(-uniform(rng, 0.015, 0.04), uniform(rng, 0.015, 0.04), 0, lift + sh * 0.5, -0.035, -0.01, 1)
    )
    parts.append(box(-w / 2, w / 2, lift, lift + sh, -0.01, face, 0))
    parts.append(box(-w / 2 + 0.02, w / 2 - 0.02, lift + 0.02, lift + sh - 0.02, face, face + 0.004, 2))
    if rng.random() < 0.5:  # bulge at the back
        parts.append(
            box(-w / 3, w / 3, lift + sh * 0.2, lift + sh * 0.8, -0.01 - uniform(rng, 0.02, 0.06), -0.01, 0)
        )
    return Furniture("monitor", parts)


def television(rng: Rng, on_stand: bool = True, max_width: float = 1.4) -> Furniture:
    """A flat TV (on a stand or bare for the wall), or a deep old CRT set; screen faces +z.

    ``max_width`` (>= 0.5 m) bounds its width, to fit the furniture it stands on."""
    max_width = max(max_width, 0.5)
    if on_stand and rng.random() < 0.2:  # CRT: a bezel box and a narrower tube box behind it
        w, d = uniform(rng, 0.45, min(0.75, max_width)), uniform(rng, 0.38, 0.5)
        h = w * uniform(rng, 0.8, 0.9)
        parts = [
            box(-w / 2, w / 2, 0, h, d / 2 - 0.1, d / 2, 0),
            box(-w / 2 + 0.08, w / 2 - 0.08, 0.05, h - 0.06, -d / 2, d / 2 - 0.1, 0),
        ]
        parts.append(box(-w / 2 + 0.05, w / 2 - 0.05, 0.05, h - 0.05, d / 2, d / 2 + 0.005, 2))
        return Furniture("television", parts)
    w = uniform(rng, 0.5, min(1.4, max_width))
    h, t = w * uniform(rng, 0.56, 0.62), uniform(rng, 0.04, 0.1)
    lift = uniform(rng, 0.05, 0.12) if on_stand else 0.0
    parts = [box(-w / 2, w / 2, lift, lift + h, -t / 2, t / 2, 0)]
    parts.append(box(-w / 2 + 0.02, w / 2 - 0.02, lift + 0.02, lift + h - 0.02, t / 2, t / 2 + 0.004, 2))
    if on_stand:
        parts += [
            cbox(uniform(rng, 0.3, 0.5), uniform(rng, 0.18, 0.25), 0, 0.02, slot=1),
            cbox(0.08, 0.03, 0, lift + 0.1, z=-t / 2 - 0.015, slot=1),
        ]
    return Furniture("television", parts)


def door(rng: Rng) -> Furniture:
    """A closed door leaf standing proud of the wall plane z = 0, its frame and a handle."""
    w, h = uniform(rng, 0.75, 0.95), uniform(rng, 1.98, 2.12)
    fw, fd, proud = uniform(rng, 0.04, 0.09), uniform(rng, 0.01, 0.03), uniform(rng, 0.008, 0.02)
    parts = [box(-w / 2, w / 2, 0, h, 0, proud, 0)]
    parts += [
        box(-w / 2 - fw, -w / 2, 0, h + fw, 0, fd, 1),
        box(w / 2, w / 2 + fw, 0, h + fw, 0, fd, 1),
        box(-w / 2, w / 2, h, h + fw, 0, fd, 1),
    ]
    side, hh = float(rng.choice([-1.0, 1.0])), uniform(rng, 0.92, 1.06)
    hx = side * (w / 2 - 0.07)
    parts.append(cyl(hx, proud + 0.004, 0.03, hh - 0.03, hh + 0.03, 1, rz=0.004))
    if rng.random() < 0.5:  # lever
        parts.append(
            box(
                min(hx, hx - side * 0.12),
                max(hx, hx - side * 0.12),
                hh - 0.01,
                hh + 0.01,
                proud + 0.045,
                proud + 0.065,
                1,
            )
        )
        parts.append(cyl(hx, proud + 0.03, 0.01, hh - 0.01, hh + 0.01, 1, rz=0.03))
    else:
        parts.append(cyl(hx, proud + 0.04, 0.025, hh - 0.025, hh + 0.025, 1, rz=0.02))
    if rng.random() < 0.5:  # panels
        for a, b in ((0.15, h * 0.45), (h * 0.52, h - 0.15)):
            parts.append(box(-w / 2 + 0.12, w / 2 - 0.12, a, b, proud, proud + 0.006, 0))
    return Furniture("door", parts)


BUILDERS: dict[str, Callable[[Rng], Furniture]] = {
    "bathtub": bathtub,
    "bed": bed,
    "bookshelf": bookshelf,
    "box": box_,
    "chair": chair,
    "desk": desk,
    "door": door,
    "dresser": dresser,
    "garbage bin": garbage_bin,
    "lamp": lamp,
    "monitor": monitor,
    "night stand": night_stand,
    "pillow": pillow,
    "sink": pedestal_sink,
    "sofa": sofa,
    "table": table,
    "television": television,
    "toilet": toilet,
}
"""Free-standing builders by class; counters come with their sinks from ``counter_with_sink``."""
