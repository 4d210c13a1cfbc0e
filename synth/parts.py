"""Solid primitives of the procedural scenes, and the furniture made of them.

Object frame (metres): ``x`` lateral, ``z`` towards the object's front, ``h`` height up from the
surface the object stands on; the origin is the middle of its base. Every primitive is upright
(its axis along gravity) and may be turned about the vertical through its centre by ``yaw``
(SPEC yaw convention: a local vector ``(x, z)`` becomes ``(cos t x + sin t z, -sin t x + cos t z)``).

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
N_SLOTS = 4  # material slots per object; each object draws N_SLOTS materials i.i.d. (class-blind)


@dataclass(frozen=True)
class Part:
    """One primitive in its object's frame: centre ``(x, h, z)``, half sizes, yaw, material slot."""

    kind: int
    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    yaw: float = 0.0
    slot: int = 0

    def corners(self) -> np.ndarray:
        """(8, 3) corners (x, h, z) of the part's bounding cuboid in the object frame."""
        sx, sh, sz = np.meshgrid([-1.0, 1.0], [-1.0, 1.0], [-1.0, 1.0], indexing="ij")
        local = np.stack([sx.ravel() * self.half[0], sh.ravel() * self.half[1], sz.ravel() * self.half[2]], 1)
        if self.kind == CYL:  # a rotated ellipse's bounding box (exact): rotate half axes, not corners
            c, s = abs(math.cos(self.yaw)), abs(math.sin(self.yaw))
            ex = math.hypot(c * self.half[0], s * self.half[2])
            ez = math.hypot(s * self.half[0], c * self.half[2])
            local = local * np.array([ex / self.half[0], 1.0, ez / self.half[2]])
        else:
            c, s = math.cos(self.yaw), math.sin(self.yaw)
            local = np.stack([c * local[:, 0] + s * local[:, 2], local[:, 1], -s * local[:, 0] + c * local[:, 2]], 1)
        return local + np.asarray(self.centre)


def box(x0: float, x1: float, h0: float, h1: float, z0: float, z1: float, slot: int = 0) -> Part:
    """An unrotated cuboid given by its extents in the object frame."""
    if not (x1 > x0 and h1 > h0 and z1 > z0):
        raise ValueError(f"box: empty extent x[{x0}, {x1}] h[{h0}, {h1}] z[{z0}, {z1}]")
    return Part(BOX, ((x0 + x1) / 2, (h0 + h1) / 2, (z0 + z1) / 2), ((x1 - x0) / 2, (h1 - h0) / 2, (z1 - z0) / 2), 0.0, slot)


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
    lo: np.ndarray = field(init=False)
    hi: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        if not self.parts:
            raise ValueError(f"furniture {self.cls!r} has no parts")
        corners = np.concatenate([p.corners() for p in self.parts])
        self.lo, self.hi = corners.min(axis=0), corners.max(axis=0)

    @property
    def size(self) -> np.ndarray:
        """(3,) extent (x, h, z) of the amodal box in the object frame."""
        return self.hi - self.lo
