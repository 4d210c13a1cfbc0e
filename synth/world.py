"""The cluttered world: rooms as full of things of no class as real ones.

``furnish_world`` furnishes a room as ``a3d.synth.rooms`` does, then adds ``clutter`` objects of
no class (``a3d.synth.unlabelled`` and ``a3d.synth.clutter``): near misses beside the classes
they resemble (stools beside chairs, benches and poufs beside sofas), things on every support
surface (bottles, electronics, cups, books, plants), storage that is no bookshelf at the walls,
radiators and panels on them, plants, bags and partitions on the floor. With ``labelled`` False
the room holds no object of the 19 classes at all (no doors either): a frame of it has nothing
to detect, which is what the false-positive measure (bench/false_positives.py) needs.

The clutter draws from the same generator after the room is furnished, so a room of a seed
keeps its class objects whatever ``clutter`` is (the camera and materials drawn after differ).
"""

from __future__ import annotations

import math

import numpy as np

from a3d.synth import clutter as cl
from a3d.synth import unlabelled as un
from a3d.synth.layout import Layout, Room
from a3d.synth.rooms import furnish

KINDS = ("surface", "storage", "floor", "wall", "partition", "window", "near-miss")
WEIGHTS = (0.42, 0.1, 0.2, 0.12, 0.04, 0.04, 0.08)  # what each added clutter object is
EMPTY_ROOM = "no-class"  # the room type of rooms without class objects


def furnish_world(
    rng: np.random.Generator, kind: str | None, clutter: int, labelled: bool = True
) -> tuple[str, Layout]:
    """A furnished room (type ``kind``, None: random) with ``clutter`` more objects of no class;
    with ``labelled`` False a room of type EMPTY_ROOM that holds clutter only."""
    if labelled:
        kind, L = furnish(rng, kind)
    else:
        kind = EMPTY_ROOM
        L = Layout(
            Room(float(rng.uniform(2.8, 6.0)), float(rng.uniform(2.8, 6.0)), float(rng.uniform(2.4, 3.0))),
            rng,
        )
        for _ in range(int(rng.integers(1, 4))):
            _window(L)
        for _ in range(int(rng.integers(2, 6))):
            _storage(L)
    add_clutter(L, clutter)
    return kind, L


def add_clutter(L: Layout, n: int) -> int:
    """Add up to ``n`` objects of no class to the layout (4n tries); how many were placed."""
    rng = L.rng
    placed, tries = 0, 0
    while placed < n and tries < 4 * n:
        tries += 1
        idx = _PLACERS[KINDS[int(rng.choice(len(KINDS), p=WEIGHTS))]](L)
        placed += idx is not None
    return placed


def _on_surface(L: Layout) -> int | None:
    rng = L.rng
    hosts = [i for i, p in enumerate(L.objects) if p.render and p.item.surfaces]
    if not hosts:
        return None
    item = [un.bottle, un.electronics, cl.small_item][int(rng.choice(3, p=[0.35, 0.3, 0.35]))](rng)
    return L.place_on(item, int(rng.choice(hosts)), tries=4)


def _storage(L: Layout) -> int | None:
    rng = L.rng
    item = un.shelving(rng) if rng.random() < 0.45 else un.filing_cabinet(rng)
    if rng.random() < 0.12:
        item = cl.cabinet(rng)  # a wardrobe
    return L.place_wall(item, corner=0.4, tries=10)


def _on_floor(L: Layout) -> int | None:
    rng = L.rng
    k = int(rng.choice(4, p=[0.4, 0.3, 0.15, 0.15]))
    if k == 0:
        return L.place_free(un.bag(rng), tries=8)
    if k == 1:
        return L.place_wall(un.floor_plant(rng), corner=0.8, gap=(0.02, 0.15), tries=8)
    if k == 2:
        return L.place_wall(un.coat_stand(rng), corner=0.6, gap=(0.05, 0.2), tries=8)
    return L.place_free(un.pouf(rng), tries=8)


def _on_wall(L: Layout) -> int | None:
    rng = L.rng
    k = int(rng.choice(3, p=[0.45, 0.3, 0.25]))
    if k == 0:
        return L.place_wall(
            un.radiator(rng), base=float(rng.uniform(0.08, 0.25)), gap=(0.0, 0.04), tries=8, corner=0
        )
    if k == 1:
        return L.place_wall(
            un.wall_panel(rng), base=float(rng.uniform(0.8, 1.2)), gap=(0, 0), tries=8, corner=0
        )
    return L.place_wall(cl.picture(rng), base=float(rng.uniform(1.1, 1.7)), gap=(0, 0), tries=6, corner=0)


def _partition(L: Layout) -> int | None:
    rng = L.rng
    yaw = float(rng.choice([0.0, math.pi / 2]))
    return L.place_free(un.partition(rng), tries=8, yaw=yaw, jitter=0.05, margin=0.3, wall_clear=0.0)


def _window(L: Layout) -> int | None:
    rng = L.rng
    return L.place_wall(cl.window(rng), base=float(rng.uniform(0.75, 1.0)), gap=(0, 0), tries=8, corner=0)


def _near_miss(L: Layout) -> int | None:
    """A stool beside a chair, a bench or pouf beside a sofa or table; free-standing without them."""
    rng = L.rng
    chairs = [i for i, p in enumerate(L.objects) if p.item.cls == "chair"]
    seats = [i for i, p in enumerate(L.objects) if p.item.cls in ("sofa", "table", "bed")]
    if chairs and rng.random() < 0.6:
        anchor = int(rng.choice(chairs))
        a = L.objects[anchor].item
        side = float(rng.choice([-1.0, 1.0]))
        return L.place_rel(
            un.stool(rng), anchor, side * (float(a.size[0]) / 2 + float(rng.uniform(0.3, 0.7))), 0.0, 0.0
        )
    if seats:
        anchor = int(rng.choice(seats))
        item = un.bench(rng) if rng.random() < 0.6 else un.pouf(rng)
        return L.place_facing(
            item,
            anchor,
            int(rng.integers(4)),
            float(rng.uniform(-0.3, 0.3)),
            float(rng.uniform(0.2, 0.6)),
            0.3,
        )
    return L.place_free(un.stool(rng) if rng.random() < 0.5 else un.bench(rng), tries=8)


_PLACERS = {
    "surface": _on_surface,
    "storage": _storage,
    "floor": _on_floor,
    "wall": _on_wall,
    "partition": _partition,
    "window": _window,
    "near-miss": _near_miss,
}
