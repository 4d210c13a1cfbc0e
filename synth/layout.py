"""Physical placement of furniture in a rectangular room.

Room frame (metres): the floor is the rectangle x in [0, width], z in [0, depth]; ``h`` is the
height above the floor. An object's pose is its origin ``(x, z)``, the height ``base`` of the
surface it stands on, and its yaw (docs/conventions.md "3D boxes": the object's local +z points along
``(sin yaw, cos yaw)`` in (x, z)). Horizontal axes and yaw are those of the tilt frame, so a
camera with heading ``phi`` sees an object of room yaw ``yaw`` at tilt yaw ``yaw - phi``.

Rules: everything stands on the floor, hangs on a wall, or stands on a support surface of
another object (its *parent*), inside that surface's rectangle; no two objects' boxes (footprint
rectangle times height interval) intersect, except a child with its parent and flat decorations
(``collides=False``); nothing crosses the room's walls, floor or ceiling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from a3d.synth.parts import Furniture

EPS = 1e-6


@dataclass(frozen=True)
class Room:
    """A box-shaped room: floor width (x) and depth (z), ceiling height (metres)."""

    width: float
    depth: float
    height: float


@dataclass
class Placed:
    """A piece of furniture at a pose in the room; ``render`` False marks a keep-out zone."""

    item: Furniture
    x: float
    z: float
    base: float
    yaw: float
    parent: int = -1
    render: bool = True
    wall: int = -1  # the wall it stands against (Layout.wall numbering), -1 if none

    def to_room(self, lx: float, lz: float) -> tuple[float, float]:
        """Room (x, z) of the object-frame point (lx, lz)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * lx + s * lz, self.z - s * lx + c * lz

    def footprint(self, margin: float = 0.0) -> list[tuple[float, float]]:
        """Room (x, z) corners of the footprint rectangle grown by ``margin``, in order around it."""
        lo, hi = self.item.lo, self.item.hi
        x0, x1, z0, z1 = lo[0] - margin, hi[0] + margin, lo[2] - margin, hi[2] + margin
        return [self.to_room(x0, z0), self.to_room(x1, z0), self.to_room(x1, z1), self.to_room(x0, z1)]

    @property
    def h0(self) -> float:
        return self.base + float(self.item.lo[1])

    @property
    def h1(self) -> float:
        return self.base + float(self.item.hi[1])


def rects_overlap(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> bool:
    """Separating-axis test of two convex quadrilaterals (touching counts as apart)."""
    for poly in (a, b):
        for i in range(4):
            (x0, z0), (x1, z1) = poly[i], poly[(i + 1) % 4]
            nx, nz = z1 - z0, x0 - x1
            pa = [nx * x + nz * z for x, z in a]
            pb = [nx * x + nz * z for x, z in b]
            if max(pa) <= min(pb) + EPS or max(pb) <= min(pa) + EPS:
                return False
    return True


def point_rect_distance(px: float, pz: float, rect: list[tuple[float, float]]) -> float:
    """Distance from a point to a rectangle given by its corners in order (0 inside)."""
    (x0, z0), (x1, z1), _, (x3, z3) = rect
    ux, uz, vx, vz = x1 - x0, z1 - z0, x3 - x0, z3 - z0
    lu, lv = math.hypot(ux, uz), math.hypot(vx, vz)
    a = ((px - x0) * ux + (pz - z0) * uz) / lu
    b = ((px - x0) * vx + (pz - z0) * vz) / lv
    da, db = max(0.0, -a, a - lu), max(0.0, -b, b - lv)
    return math.hypot(da, db)


class Layout:
    """The furniture of one room, grown object by object under the placement rules."""

    def __init__(self, room: Room, rng: np.random.Generator) -> None:
        self.room = room
        self.rng = rng
        self.objects: list[Placed] = []

    # ------------------------------------------------------------------ checks

    def fits(self, p: Placed, margin: float = 0.02, wall_clear: float = 0.0) -> bool:
        """True if p stays inside the room (``wall_clear`` from the walls) and clear (by ``margin``)
        of every object but its parent."""
        if p.h0 < -EPS or p.h1 > self.room.height - 0.02:
            return False
        for x, z in p.footprint(wall_clear):
            if not (-EPS <= x <= self.room.width + EPS and -EPS <= z <= self.room.depth + EPS):
                return False
        if not p.item.collides:
            return True
        mine = p.footprint(margin)
        for j, q in enumerate(self.objects):
            if j == p.parent or not q.item.collides:
                continue
            if min(p.h1, q.h1) - max(p.h0, q.h0) <= 1e-4:
                continue
            if rects_overlap(mine, q.footprint()):
                return False
        return True

    def add(self, p: Placed, margin: float = 0.02, wall_clear: float = 0.0) -> int | None:
        """Append p if it fits; its index, or None."""
        if not self.fits(p, margin, wall_clear):
            return None
        self.objects.append(p)
        return len(self.objects) - 1

    # ------------------------------------------------------------------ walls

    def wall(self, k: int) -> tuple[tuple[float, float], tuple[float, float], float, float]:
        """Wall k (0: z = 0, 1: x = width, 2: z = depth, 3: x = 0): start corner, tangent, yaw, length.

        An object of that yaw has its local +x along the tangent and +z pointing into the room.
        """
        W, D = self.room.width, self.room.depth
        return [
            ((0.0, 0.0), (1.0, 0.0), 0.0, W),
            ((W, 0.0), (0.0, 1.0), -math.pi / 2, D),
            ((W, D), (-1.0, 0.0), math.pi, W),
            ((0.0, D), (0.0, -1.0), math.pi / 2, D),
        ][k]

    def at_wall(self, item: Furniture, k: int, s: float, gap: float = 0.0, base: float = 0.0) -> Placed:
        """Pose with the item's back ``gap`` from wall k and its origin at ``s`` along the wall."""
        (x0, z0), (tx, tz), yaw, _ = self.wall(k)
        d = gap - float(item.lo[2])
        nx, nz = math.sin(yaw), math.cos(yaw)
        return Placed(item, x0 + s * tx + d * nx, z0 + s * tz + d * nz, base, yaw, wall=k)

    def place_wall(
        self,
        item: Furniture,
        walls: tuple[int, ...] = (0, 1, 2, 3),
        base: float = 0.0,
        tries: int = 25,
        gap: tuple[float, float] = (0.0, 0.04),
        corner: float = 0.25,
    ) -> int | None:
        """Against a random wall at a random free spot (a corner with probability ``corner``)."""
        rng = self.rng
        for _ in range(tries):
            k = int(rng.choice(walls))
            length = self.wall(k)[3]
            s0, s1 = -float(item.lo[0]), length - float(item.hi[0])
            if s1 < s0:
                continue
            s = float(rng.choice([s0, s1])) if rng.random() < corner else float(rng.uniform(s0, s1))
            idx = self.add(self.at_wall(item, k, s, float(rng.uniform(*gap)), base))
            if idx is not None:
                return idx
        return None

    # ------------------------------------------------------------------ floor and relations

    def place_free(
        self,
        item: Furniture,
        tries: int = 25,
        yaw: float | None = None,
        jitter: float = 0.0,
        margin: float = 0.02,
        wall_clear: float = 0.0,
    ) -> int | None:
        """Anywhere on the floor (``wall_clear`` from the walls, ``margin`` from other objects);
        random yaw unless ``yaw`` (plus up to ``jitter``) is given."""
        rng = self.rng
        for _ in range(tries):
            y = (
                float(rng.uniform(0, 2 * math.pi))
                if yaw is None
                else yaw + float(rng.uniform(-jitter, jitter))
            )
            p = Placed(
                item, float(rng.uniform(0, self.room.width)), float(rng.uniform(0, self.room.depth)), 0.0, y
            )
            idx = self.add(p, margin, wall_clear)
            if idx is not None:
                return idx
        return None

    def place_rel(
        self, item: Furniture, anchor: int, lx: float, lz: float, rel_yaw: float, margin: float = 0.02
    ) -> int | None:
        """On the anchor's floor level at (lx, lz) in the anchor's frame, turned by rel_yaw."""
        a = self.objects[anchor]
        x, z = a.to_room(lx, lz)
        return self.add(Placed(item, x, z, a.base, a.yaw + rel_yaw), margin)

    def place_beside(self, item: Furniture, anchor: int, side: float, gap: float) -> int | None:
        """Next to the anchor's left (-1) or right (+1) side, backs aligned, same yaw."""
        a = self.objects[anchor].item
        lx = (
            float(a.hi[0]) + gap - float(item.lo[0]) if side > 0 else float(a.lo[0]) - gap - float(item.hi[0])
        )
        return self.place_rel(item, anchor, lx, float(a.lo[2] - item.lo[2]), 0.0)

    def place_facing(
        self, item: Furniture, anchor: int, side: int, along: float, gap: float, jitter: float = 0.0
    ) -> int | None:
        """At side ``side`` (0: +z, 1: +x, 2: -z, 3: -x of the anchor frame) facing the anchor.

        ``along`` shifts it along that side; ``gap`` is the clearance between the anchor's edge and
        the item's front (its local +z extent); the yaw is off by up to ``jitter``.
        """
        a = self.objects[anchor].item
        nx, nz = [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0)][side]
        edge = [float(a.hi[2]), float(a.hi[0]), -float(a.lo[2]), -float(a.lo[0])][side]
        dist = edge + gap + float(item.hi[2])
        lx, lz = nx * dist - nz * along, nz * dist + nx * along
        rel = math.atan2(-nx, -nz) + float(self.rng.uniform(-jitter, jitter))
        return self.place_rel(item, anchor, lx, lz, rel)

    def place_on(
        self,
        item: Furniture,
        parent: int,
        tries: int = 12,
        rel_yaw: float = 0.0,
        jitter: float = math.pi,
        back: bool = False,
    ) -> int | None:
        """On a random support surface of ``parent``, inside its rectangle (near its back if ``back``)."""
        rng = self.rng
        par = self.objects[parent]
        if not par.item.surfaces:
            return None
        lo, hi = item.lo, item.hi
        for _ in range(tries):
            srf = par.item.surfaces[int(rng.integers(len(par.item.surfaces)))]
            rel = rel_yaw + float(rng.uniform(-jitter, jitter))
            c, s = math.cos(rel), math.sin(rel)
            xs = [c * x + s * z for x in (lo[0], hi[0]) for z in (lo[2], hi[2])]
            zs = [-s * x + c * z for x in (lo[0], hi[0]) for z in (lo[2], hi[2])]
            ox0, ox1 = srf.x0 - min(xs), srf.x1 - max(xs)
            oz0, oz1 = srf.z0 - min(zs), srf.z1 - max(zs)
            if ox1 < ox0 or oz1 < oz0:
                continue
            oz = oz0 + (oz1 - oz0) * float(rng.uniform(0, 0.25)) if back else float(rng.uniform(oz0, oz1))
            x, z = par.to_room(float(rng.uniform(ox0, ox1)), oz)
            idx = self.add(Placed(item, x, z, par.base + srf.h, par.yaw + rel, parent=parent), 0.01)
            if idx is not None:
                return idx
        return None
