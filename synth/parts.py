"""Solid primitives of the procedural scenes, and the furniture made of them.

Object frame (metres): ``x`` lateral, ``z`` towards the object's front, ``h`` height up from the
surface the object stands on; the origin is the middle of its base. Every primitive is upright
(its axis along gravity) and may be turned about the vertical through its centre by ``yaw``
(the yaw convention of docs/conventions.md "3D boxes": a local vector ``(x, z)`` becomes
``(cos t x + sin t z, -sin t x + cos t z)``).

Two kinds: ``BOX`` (a cuboid, half sizes ``(hx, hh, hz)``) and ``CYL`` (a vertical elliptic
cylinder, radii ``hx`` and ``hz``, half height ``hh``). Both are solids: what a camera sees of an
object is the union of its parts' surfaces, and its amodal 3D box is the tight box of the parts
in the object frame (``Furniture.extent``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

BOX, CYL = 0, 1
N_SLOTS = 4  # material slots per object; each object draws N_SLOTS materials i.i.d. (class-blind by default)


@dataclass(frozen=True)
class Part:
    """One primitive in its object's frame: centre ``(x, h, z)``, half sizes, yaw, material slot."""

    kind: int
    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    yaw: float = 0.0
    slot: int = 0

    def extent(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Tight (lo, hi) corners (x, h, z) of the part in the object frame (exact for both kinds)."""
        c, s = abs(math.cos(self.yaw)), abs(math.sin(self.yaw))
        hx, hh, hz = self.half
        if self.kind == CYL:  # a turned ellipse's half extents
            ex, ez = math.hypot(c * hx, s * hz), math.hypot(s * hx, c * hz)
        else:  # a turned rectangle's half extents
            ex, ez = c * hx + s * hz, s * hx + c * hz
        x, h, z = self.centre
        return (x - ex, h - hh, z - ez), (x + ex, h + hh, z + ez)


def box(x0: float, x1: float, h0: float, h1: float, z0: float, z1: float, slot: int = 0) -> Part:
    """An unrotated cuboid given by its extents in the object frame."""
    if not (x1 > x0 and h1 > h0 and z1 > z0):
        raise ValueError(f"box: empty extent x[{x0}, {x1}] h[{h0}, {h1}] z[{z0}, {z1}]")
    return Part(
        BOX,
        ((x0 + x1) / 2, (h0 + h1) / 2, (z0 + z1) / 2),
        ((x1 - x0) / 2, (h1 - h0) / 2, (z1 - z0) / 2),
        0.0,
        slot,
    )


def cbox(w: float, d: float, h0: float, h1: float, x: float = 0.0, z: float = 0.0, slot: int = 0) -> Part:
    """A cuboid of width ``w`` (x) and depth ``d`` (z) centred at ``(x, z)``, from height h0 to h1."""
    return box(x - w / 2, x + w / 2, h0, h1, z - d / 2, z + d / 2, slot)


def cyl(x: float, z: float, rx: float, h0: float, h1: float, slot: int = 0, rz: float | None = None) -> Part:
    """A vertical (elliptic) cylinder centred at ``(x, z)`` with radii ``rx``, ``rz`` (default rx)."""
    rz = rx if rz is None else rz
    if not (rx > 0 and rz > 0 and h1 > h0):
        raise ValueError(f"cyl: bad radii ({rx}, {rz}) or heights [{h0}, {h1}]")
    return Part(CYL, (x, (h0 + h1) / 2, z), (rx, (h1 - h0) / 2, rz), 0.0, slot)


@dataclass(frozen=True)
class Surface:
    """A horizontal rectangle others may stand on: x in [x0, x1], z in [z0, z1] at height ``h``."""

    x0: float
    x1: float
    z0: float
    z1: float
    h: float


@dataclass
class Furniture:
    """One object in its own frame: class (None for unannotated clutter), parts, support surfaces.

    ``lo``/``hi`` (x, h, z) are the tight extent of all parts (its amodal box in the object
    frame); ``collides`` False marks flat decorations (rugs) other objects may overlap.
    """

    cls: str | None
    parts: list[Part]
    surfaces: list[Surface] = field(default_factory=list)
    collides: bool = True
    glow: int = -1  # the part that emits light with real light (a window pane), -1 none
    lo: np.ndarray = field(init=False)
    hi: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        if not self.parts:
            raise ValueError(f"furniture {self.cls!r} has no parts")
        ext = [p.extent() for p in self.parts]
        self.lo = np.min([e[0] for e in ext], axis=0)
        self.hi = np.max([e[1] for e in ext], axis=0)

    @property
    def size(self) -> np.ndarray:
        """(3,) extent (x, h, z) of the amodal box in the object frame."""
        return self.hi - self.lo
