"""Room types and what furnishes them: bedroom, living room, dining room, kitchen, office,
bathroom and classroom, each a recipe of furniture groups placed by ``a3d.synth.layout``.

The recipes set the class statistics: chairs come in sets (dining sets, desks, classrooms) and
are the most frequent class; toilets and bathtubs only appear in bathrooms; small objects
(pillows, lamps, monitors, boxes, clutter) stand on the large ones, which makes occlusion.
"""

from __future__ import annotations

import math

import numpy as np

from a3d.synth import clutter as cl
from a3d.synth import furniture as fu
from a3d.synth.layout import Layout, Placed, Room
from a3d.synth.parts import Furniture, box

ROOM_TYPES: dict[str, float] = {
    "bedroom": 0.2,
    "living": 0.17,
    "dining": 0.1,
    "kitchen": 0.13,
    "office": 0.17,
    "bathroom": 0.13,
    "classroom": 0.1,
}
"""Room type -> probability."""

_SIZES = {  # (width range, depth range) in metres
    "bedroom": ((3.0, 4.6), (3.0, 5.0)),
    "living": ((3.5, 5.5), (3.5, 6.0)),
    "dining": ((3.0, 5.0), (3.0, 5.0)),
    "kitchen": ((2.6, 4.2), (3.0, 4.6)),
    "office": ((3.0, 5.5), (3.0, 6.0)),
    "bathroom": ((1.8, 3.2), (2.0, 3.5)),
    "classroom": ((4.5, 6.5), (4.5, 6.5)),
}


def _n(rng: np.random.Generator, lo: int, hi: int) -> int:
    return int(rng.integers(lo, hi + 1))


def _p(rng: np.random.Generator, p: float) -> bool:
    return bool(rng.random() < p)


# ----------------------------------------------------------------------------- groups


def _doors_windows(L: Layout) -> None:
    """1-2 doors with a clear swing zone in front, windows and pictures on the walls."""
    rng = L.rng
    for _ in range(_n(rng, 1, 2)):
        for _ in range(10):
            door = fu.door(rng)
            k = int(rng.integers(4))
            length = L.wall(k)[3]
            if length < door.size[0] + 0.1:
                continue
            p = L.at_wall(door, k, float(rng.uniform(-door.lo[0] + 0.05, length - door.hi[0] - 0.05)))
            swing = Furniture(
                None,
                [
                    box(
                        float(door.lo[0]),
                        float(door.hi[0]),
                        0,
                        2.0,
                        float(door.hi[2]),
                        float(door.hi[2]) + 0.8,
                    )
                ],
            )
            keep = Placed(swing, p.x, p.z, 0.0, p.yaw, render=False)
            if L.fits(p) and L.fits(keep):
                L.objects += [p, keep]
                break
    for _ in range(_n(rng, 0, 2)):
        L.place_wall(cl.window(rng), base=float(rng.uniform(0.75, 1.0)), gap=(0, 0), tries=8, corner=0)


def _pictures(L: Layout, n: int) -> None:
    for _ in range(n):
        L.place_wall(cl.picture(L.rng), base=float(L.rng.uniform(1.1, 1.7)), gap=(0, 0), tries=6, corner=0)


def _tv_on(L: Layout, idx: int | None) -> int | None:
    """A TV that fits on object idx's top (facing its front)."""
    if idx is None:
        return None
    width = float(L.objects[idx].item.size[0]) - 0.08
    return L.place_on(fu.television(L.rng, max_width=width), idx, jitter=0.3)


def _clutter(L: Layout, idx: int | None, n: int) -> None:
    """Up to n small items (cups, books, plants ... and sometimes a box) on object idx."""
    if idx is None:
        return
    for _ in range(n):
        item = fu.box_(L.rng) if _p(L.rng, 0.25) else cl.small_item(L.rng)
        L.place_on(item, idx, tries=4)


def _chairs_around(L: Layout, table: int | None, n: int, jitter: float = 0.3) -> None:
    """Up to n matching chairs at free seats along the table's sides, facing it, pulled out at random."""
    if table is None:
        return
    rng = L.rng
    t = L.objects[table].item
    chair = fu.chair(rng, "legs" if _p(rng, 0.8) else None)  # one model (and later its materials) for the set
    seats = []
    for side in range(4):
        span = float(t.size[0] if side in (0, 2) else t.size[2])
        cap = max(1, int(span / 0.6))
        seats += [(side, ((k + 0.5) / cap - 0.5) * span) for k in range(cap)]
    for i in rng.permutation(len(seats))[:n]:
        side, along = seats[i]
        gap = float(rng.uniform(0.0, 0.35)) + 0.04
        for attempt in range(4):  # pull the chair further out until it fits
            if (
                L.place_facing(
                    chair, table, side, along + float(rng.uniform(-0.05, 0.05)), gap + 0.08 * attempt, jitter
                )
                is not None
            ):
                break


def _bed_group(L: Layout) -> None:
    rng = L.rng
    bed = L.place_wall(fu.bed(rng), tries=30, gap=(0.0, 0.03))
    if bed is None:
        return
    for _ in range(_n(rng, 2, 5)):
        L.place_on(fu.pillow(rng), bed, rel_yaw=0.0, jitter=0.2, back=True)
    for side in (-1.0, 1.0):
        if _p(rng, 0.75):
            ns = L.place_beside(fu.night_stand(rng), bed, side, float(rng.uniform(0.02, 0.1)))
            if ns is not None and _p(rng, 0.6):
                L.place_on(fu.lamp(rng, floor=False), ns, back=True)
            _clutter(L, ns, _n(rng, 0, 2))


def _sofa_group(L: Layout) -> None:
    rng = L.rng
    sofa = L.place_wall(fu.sofa(rng), tries=30, gap=(0.0, 0.1))
    if sofa is None:
        return
    for _ in range(_n(rng, 1, 5)):
        L.place_on(fu.pillow(rng, upright=True), sofa, rel_yaw=0.0, jitter=0.35, back=True)
    table = None
    if _p(rng, 0.75):
        t = fu.table(rng, "coffee")
        table = L.place_rel(
            t,
            sofa,
            float(rng.uniform(-0.2, 0.2)),
            float(L.objects[sofa].item.hi[2] + rng.uniform(0.3, 0.55) - t.lo[2]),
            float(rng.uniform(-0.1, 0.1)),
        )
        _clutter(L, table, _n(rng, 0, 3))
    for side in (-1.0, 1.0):
        if _p(rng, 0.3):
            st = L.place_beside(
                fu.night_stand(rng) if _p(rng, 0.5) else fu.table(rng, "side"), sofa, side, 0.05
            )
            if st is not None and _p(rng, 0.6):
                L.place_on(fu.lamp(rng, floor=False), st)
        elif _p(rng, 0.25):
            L.place_beside(fu.lamp(rng, floor=True), sofa, side, 0.1)
    if table is not None:
        for side in (1, 3):
            if _p(rng, 0.45):
                L.place_facing(
                    fu.chair(rng, "armchair"),
                    table,
                    side,
                    float(rng.uniform(-0.2, 0.2)),
                    float(rng.uniform(0.25, 0.6)),
                    0.4,
                )


def _tv_group(L: Layout) -> None:
    rng = L.rng
    if _p(rng, 0.3):  # on the wall
        L.place_wall(
            fu.television(rng, on_stand=False), base=float(rng.uniform(0.9, 1.5)), gap=(0.02, 0.06), corner=0
        )
        return
    stand = L.place_wall(fu.dresser(rng) if _p(rng, 0.6) else fu.table(rng, "side"), tries=20)
    if stand is not None:
        _tv_on(L, stand)
        _clutter(L, stand, _n(rng, 0, 2))


def _desk_group(L: Layout, at_wall: bool = True) -> int | None:
    rng = L.rng
    d = fu.desk(rng)
    idx = (
        L.place_wall(d, tries=20)
        if at_wall
        else L.place_free(d, yaw=float(rng.choice([0, math.pi / 2, math.pi, -math.pi / 2])), jitter=0.1)
    )
    if idx is None:
        return None
    for _ in range(_n(rng, 1, 2) if _p(rng, 0.8) else 0):
        L.place_on(fu.monitor(rng), idx, rel_yaw=0.0, jitter=0.35, back=True)
    if _p(rng, 0.3):
        L.place_on(fu.lamp(rng, floor=False), idx, back=True)
    _clutter(L, idx, _n(rng, 0, 3))
    if _p(rng, 0.85):
        L.place_facing(
            fu.chair(rng), idx, 0, float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.05, 0.5)) + 0.06, 0.6
        )
    if _p(rng, 0.35):
        L.place_beside(fu.garbage_bin(rng), idx, float(rng.choice([-1.0, 1.0])), 0.05)
    return idx


def _dining_set(L: Layout, n_chairs: tuple[int, int]) -> None:
    rng = L.rng
    t = fu.table(rng, "round" if _p(rng, 0.2) else "dining")
    yaw = float(rng.uniform(0, 2 * math.pi)) if _p(rng, 0.3) else float(rng.choice([0, math.pi / 2]))
    idx = L.place_free(t, yaw=yaw, jitter=0.15, margin=0.6, wall_clear=0.55 if _p(rng, 0.8) else 0.0)
    _clutter(L, idx, _n(rng, 0, 4))
    _chairs_around(L, idx, _n(rng, *n_chairs))


def _storage(L: Layout, shelves: int, boxes: int) -> None:
    """Bookshelves at walls (boxes on low ones), and boxes on the floor, some stacked."""
    rng = L.rng
    for _ in range(shelves):
        idx = L.place_wall(fu.bookshelf(rng), corner=0.4, tries=15)
        if idx is not None and L.objects[idx].item.hi[1] < 1.3 and _p(rng, 0.5):
            L.place_on(fu.box_(rng), idx)
    for _ in range(boxes):
        b = fu.box_(rng)
        idx = L.place_wall(b, corner=0.5, tries=8) if _p(rng, 0.6) else L.place_free(b, tries=8)
        while idx is not None and _p(rng, 0.35):
            idx = L.place_on(fu.box_(rng), idx, jitter=0.3)


def _extras(L: Layout) -> None:
    """What any room may hold: garbage bins, a floor lamp, a wardrobe, loose chairs and boxes."""
    rng = L.rng
    for _ in range(_n(rng, 0, 2)):
        L.place_wall(fu.garbage_bin(rng), corner=0.5) if _p(rng, 0.6) else L.place_free(fu.garbage_bin(rng))
    if _p(rng, 0.25):
        L.place_wall(fu.lamp(rng, floor=True), corner=0.7, gap=(0.05, 0.2))
    if _p(rng, 0.3):
        L.place_wall(cl.cabinet(rng), tries=10)
    for _ in range(_n(rng, 1, 3)):
        L.place_free(fu.chair(rng), tries=10)
    _storage(L, 0, _n(rng, 0, 2))
    if _p(rng, 0.35):  # a side table with a lamp, a TV or a box on it
        idx = L.place_wall(fu.table(rng, "side"), corner=0.5)
        if idx is not None:
            what = int(rng.choice(3, p=[0.5, 0.25, 0.25]))
            if what == 1:
                _tv_on(L, idx)
            else:
                L.place_on(fu.lamp(rng, floor=False) if what == 0 else fu.box_(rng), idx, jitter=0.4)


# ----------------------------------------------------------------------------- rooms


def _bedroom(L: Layout) -> None:
    rng = L.rng
    _bed_group(L)
    if _p(rng, 0.7):
        idx = L.place_wall(fu.dresser(rng), tries=15)
        if idx is not None:
            if _p(rng, 0.4):
                _tv_on(L, idx)
            if _p(rng, 0.5):
                L.place_on(fu.lamp(rng, floor=False), idx)
            _clutter(L, idx, _n(rng, 0, 3))
    if _p(rng, 0.5):
        _desk_group(L)
    _storage(L, _n(rng, 0, 1), _n(rng, 1, 5))
    if _p(rng, 0.15):
        _sofa_group(L)
    elif _p(rng, 0.3):
        L.place_free(fu.chair(rng, "armchair"), tries=10)


def _living(L: Layout) -> None:
    rng = L.rng
    _sofa_group(L)
    if _p(rng, 0.4):
        _sofa_group(L)
    if _p(rng, 0.85):
        _tv_group(L)
    _storage(L, _n(rng, 0, 2), _n(rng, 0, 3))
    if _p(rng, 0.5):
        _dining_set(L, (2, 6))
    if _p(rng, 0.2):
        _desk_group(L)


def _dining(L: Layout) -> None:
    rng = L.rng
    _dining_set(L, (4, 8))
    if _p(rng, 0.25):
        _dining_set(L, (2, 4))
    if _p(rng, 0.5):
        idx = L.place_wall(fu.dresser(rng), tries=15)
        _clutter(L, idx, _n(rng, 0, 3))
    if _p(rng, 0.4):
        _counter(L, sink=_p(rng, 0.4))
    _storage(L, _n(rng, 0, 1), _n(rng, 0, 3))


def _counter(
    L: Layout, sink: bool, length: tuple[float, float] = (1.2, 3.0), stools: float = 0.0
) -> int | None:
    """A counter at a wall (with a drop-in sink), wall cabinets above it, things on top, and
    (probability ``stools``) chairs in front of it."""
    rng = L.rng
    for _ in range(8):
        length_ = float(rng.uniform(*length))
        if sink:
            c, s, (sx, sz, sbase) = fu.counter_with_sink(rng, length_)
        else:
            c = fu.counter(
                rng, length_, float(rng.uniform(0.55, 0.65)), float(rng.uniform(0.82, 0.94)), None, 0.0
            )
        idx = L.place_wall(c, tries=4, gap=(0.0, 0.02), corner=0.5)
        if idx is None:
            continue
        par = L.objects[idx]
        if sink:
            x, z = par.to_room(sx, sz)
            L.objects.append(Placed(s, x, z, sbase, par.yaw, parent=idx))
        for _ in range(_n(rng, 0, 4)):
            item = fu.box_(rng) if _p(rng, 0.35) else cl.small_item(rng)
            if _p(rng, 0.08):
                item = fu.television(rng, max_width=0.8)
            L.place_on(item, idx, jitter=0.4)
        if _p(rng, 0.5):
            cab = cl.cabinet(rng, wall_hung=True)
            for _ in range(3):
                q = L.at_wall(cab, par.wall, 0.0, 0.0, float(rng.uniform(1.4, 1.55)))
                lx = (
                    float(rng.uniform(c.lo[0] - cab.lo[0], c.hi[0] - cab.hi[0]))
                    if c.size[0] > cab.size[0]
                    else 0.0
                )
                q.x, q.z = par.to_room(lx, float(c.lo[2] - cab.lo[2]))
                if L.add(q) is not None:
                    break
        if _p(rng, stools):
            stool = fu.chair(rng)
            for _ in range(_n(rng, 1, 3)):
                along = float(rng.uniform(-0.4, 0.4)) * float(c.size[0])
                L.place_facing(stool, idx, 0, along, float(rng.uniform(0.05, 0.4)), 0.4)
        return idx
    return None


def _kitchen(L: Layout) -> None:
    rng = L.rng
    _counter(L, sink=True, stools=0.2)
    if _p(rng, 0.6):
        _counter(L, sink=_p(rng, 0.15), stools=0.3)
    if _p(rng, 0.4):
        L.place_wall(cl.cabinet(rng), tries=10)  # a fridge-like tall block
    if _p(rng, 0.8):
        _dining_set(L, (2, 6))
    if _p(rng, 0.7):
        L.place_wall(fu.garbage_bin(rng), corner=0.5)
    _storage(L, 0, _n(rng, 0, 3))


def _office(L: Layout) -> None:
    rng = L.rng
    for _ in range(_n(rng, 2, 5)):
        _desk_group(L, at_wall=_p(rng, 0.7))
    _storage(L, _n(rng, 1, 3), _n(rng, 1, 5))
    if _p(rng, 0.35):
        _dining_set(L, (3, 6))
    if _p(rng, 0.15):
        _sofa_group(L)
    for _ in range(_n(rng, 1, 4)):
        L.place_free(fu.chair(rng), tries=8)


def _bathroom(L: Layout) -> None:
    rng = L.rng
    L.place_wall(fu.bathtub(rng), corner=0.8, tries=30, gap=(0.0, 0.01))
    L.place_wall(fu.toilet(rng), tries=30, gap=(0.0, 0.05))
    if _p(rng, 0.55):
        _counter(L, sink=True, length=(0.7, 1.5))
    else:
        L.place_wall(fu.pedestal_sink(rng), tries=30, gap=(0.0, 0.02))
    if _p(rng, 0.6):
        L.place_wall(fu.garbage_bin(rng), corner=0.6)
    _storage(L, 0, _n(rng, 0, 2))
    if _p(rng, 0.3):
        L.place_wall(cl.cabinet(rng, wall_hung=True), base=float(rng.uniform(1.3, 1.6)), corner=0)


def _classroom(L: Layout) -> None:
    rng = L.rng
    if _p(rng, 0.5):  # conference: one long table, many chairs
        _dining_set(L, (6, 12))
    else:  # rows of desks
        for _ in range(_n(rng, 3, 6)):
            _desk_group(L, at_wall=_p(rng, 0.3))
    if _p(rng, 0.5):
        L.place_wall(
            fu.television(rng, on_stand=False), base=float(rng.uniform(1.0, 1.5)), gap=(0.02, 0.06), corner=0
        )
    _storage(L, _n(rng, 0, 2), _n(rng, 0, 3))
    for _ in range(_n(rng, 1, 5)):
        L.place_free(fu.chair(rng), tries=8)


_RECIPES = {
    "bedroom": _bedroom,
    "living": _living,
    "dining": _dining,
    "kitchen": _kitchen,
    "office": _office,
    "bathroom": _bathroom,
    "classroom": _classroom,
}


def furnish(rng: np.random.Generator, kind: str | None = None) -> tuple[str, Layout]:
    """A random room of a random (or the given) type, furnished; returns (type, layout)."""
    kind = kind or str(rng.choice(list(ROOM_TYPES), p=list(ROOM_TYPES.values())))
    (w0, w1), (d0, d1) = _SIZES[kind]
    room = Room(float(rng.uniform(w0, w1)), float(rng.uniform(d0, d1)), float(rng.uniform(2.4, 3.0)))
    L = Layout(room, rng)
    _doors_windows(L)
    _RECIPES[kind](L)
    if kind != "bathroom":
        _extras(L)
    if _p(rng, 0.4):
        L.place_free(cl.rug(rng))
    _pictures(L, _n(rng, 0, 3))
    return kind, L
