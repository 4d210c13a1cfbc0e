"""Exact per-pixel ray casting of upright cuboids and elliptic cylinders (numpy, float32).

A ``RayGrid`` is a regular grid of pixel rays of a pinhole view placed anywhere in the tilt
frame: ray (i, j) is ``origin + t d`` with ``d = rot @ K^-1 [u, v, 1]`` at ``u = u0 + stride j``,
``v = v0 + stride i``; as d has unit view-z, ``t`` is the view's z-depth (the camera's depth map).

Every primitive is tested only inside the grid rectangle its bounding cuboid projects to (edges
cut at the near plane, ``a3d.runtime.structures.geometry.box_edges_clipped``), as a slab test in the part's
own frame: three intervals of t (x, y and z slabs, or the radial interval of the cylinder's
quadric and the y slab) whose intersection is non-empty where the ray hits; the entry ``t`` is
the depth. The objects of a scene are drawn one by one into a z-buffer; each object is also
rendered alone (its own parts only), which gives its unoccluded pixel count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from a3d.runtime.structures.geometry import box_edges_clipped
from a3d.synth.parts import CYL

NEAR = 0.05  # metres; nothing closer to the view is drawn


@dataclass(frozen=True)
class PartArrays:
    """P primitives in the tilt frame: ``kind`` (P,) (parts.BOX / parts.CYL), ``centre`` (P, 3),
    ``half`` (P, 3) half sizes along the part's own (x, y, z) (y down), ``yaw`` (P,) tilt-frame yaw,
    ``obj`` (P,) owning object, ascending, ``material`` (P,) material index, ``tint`` (P, 3)."""

    kind: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    obj: np.ndarray
    material: np.ndarray
    tint: np.ndarray

    def __len__(self) -> int:
        return len(self.kind)


@dataclass(frozen=True)
class RayGrid:
    """Rays of a pinhole view (see the module docstring); ``d`` is (3, rows, cols) float32."""

    origin: np.ndarray
    rot: np.ndarray
    K: np.ndarray
    u0: float
    v0: float
    stride: float
    d: np.ndarray

    @classmethod
    def make(
        cls,
        origin: np.ndarray,
        rot: np.ndarray,
        K: np.ndarray,
        shape: tuple[int, int],
        u0: float = 0.0,
        v0: float = 0.0,
        stride: float = 1.0,
    ) -> RayGrid:
        rows, cols = shape
        x = (u0 + stride * np.arange(cols) - K[0, 2]) / K[0, 0]
        y = (v0 + stride * np.arange(rows) - K[1, 2]) / K[1, 1]
        d = (
            rot[:, 0, None, None] * x[None, None, :]
            + rot[:, 1, None, None] * y[None, :, None]
            + rot[:, 2, None, None]
        )
        return cls(
            np.asarray(origin, np.float64),
            np.asarray(rot, np.float64),
            np.asarray(K, np.float64),
            u0,
            v0,
            stride,
            np.ascontiguousarray(d, dtype=np.float32),
        )

    @property
    def shape(self) -> tuple[int, int]:
        return self.d.shape[1], self.d.shape[2]

    def points(self, t: np.ndarray) -> np.ndarray:
        """(3, rows, cols) tilt-frame points at ray parameters t."""
        return self.origin[:, None, None].astype(np.float32) + self.d * t[None]

    def rects(self, parts: PartArrays) -> np.ndarray:
        """(P, 4) int grid rectangles [r0, r1, c0, c1) covering each part's projection (may be empty)."""
        n = len(parts)
        if n == 0:
            return np.zeros((0, 4), np.int64)
        half = parts.half  # a cylinder's ellipse lies inside the cuboid of its radii, turned alike
        centre_view = (parts.centre - self.origin) @ self.rot  # rot.T @ (c - o), row-wise
        boxes = np.column_stack([centre_view, 2 * half[:, 0], 2 * half[:, 2], 2 * half[:, 1], parts.yaw])
        seg, valid = box_edges_clipped(boxes, self.rot, NEAR)
        pts = seg.reshape(n, 24, 3)
        ok = np.repeat(valid, 2, axis=1)
        z = np.where(ok, pts[..., 2], 1.0)
        u = (self.K[0, 0] * pts[..., 0] / z + self.K[0, 2] - self.u0) / self.stride
        v = (self.K[1, 1] * pts[..., 1] / z + self.K[1, 2] - self.v0) / self.stride
        big = 1e9
        rows, cols = self.shape
        c0 = np.floor(np.where(ok, u, big).min(axis=1)).clip(-1, cols + 1)
        c1 = np.ceil(np.where(ok, u, -big).max(axis=1)).clip(-1, cols + 1) + 1
        r0 = np.floor(np.where(ok, v, big).min(axis=1)).clip(-1, rows + 1)
        r1 = np.ceil(np.where(ok, v, -big).max(axis=1)).clip(-1, rows + 1) + 1
        out = np.column_stack([r0, r1, c0, c1]).astype(np.int64)
        out[:, :2] = out[:, :2].clip(0, rows)
        out[:, 2:] = out[:, 2:].clip(0, cols)
        out[~ok.any(axis=1)] = 0
        return out

    def hit(self, parts: PartArrays, p: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Ray parameter of the first hit of part p on rows r0:r1, cols c0:c1 (inf where missed)."""
        dx, dy, dz = self.d[0, r0:r1, c0:c1], self.d[1, r0:r1, c0:c1], self.d[2, r0:r1, c0:c1]
        ca, sa = math.cos(parts.yaw[p]), math.sin(parts.yaw[p])
        qx, qy, qz = self.origin - parts.centre[p]
        ox, oz = ca * qx - sa * qz, sa * qx + ca * qz  # R_y(-yaw) (origin - centre)
        hx, hy, hz = parts.half[p]
        lx = ca * dx - sa * dz
        lz = sa * dx + ca * dz
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            iy = np.float32(1.0) / dy
            ay, by = np.float32(-qy) * iy, np.float32(hy) * np.abs(iy)
            t_lo, t_hi = ay - by, ay + by
            if parts.kind[p] == CYL:
                X, Z = lx / np.float32(hx), lz / np.float32(hz)
                OX, OZ = np.float32(ox / hx), np.float32(oz / hz)
                a = X * X + Z * Z
                b = OX * X + OZ * Z
                c = np.float32(OX * OX + OZ * OZ - 1.0)
                root = np.sqrt(b * b - a * c)  # NaN where the ray misses the infinite cylinder
                ia = np.float32(1.0) / a
                t_lo = np.maximum(t_lo, (-b - root) * ia)
                t_hi = np.minimum(t_hi, (root - b) * ia)
            else:
                for l_, o_, h_ in ((lx, ox, hx), (lz, oz, hz)):
                    il = np.float32(1.0) / l_
                    a_, b_ = np.float32(-o_) * il, np.float32(h_) * np.abs(il)
                    t_lo = np.maximum(t_lo, a_ - b_)
                    t_hi = np.minimum(t_hi, a_ + b_)
            return np.where((t_lo <= t_hi) & (t_lo > NEAR), t_lo, np.float32(np.inf))


@dataclass
class Render:
    """A z-buffer: ``t`` (rows, cols) float32 ray parameters (inf: nothing), ``part`` (rows, cols)
    int32 (-1: nothing, else the part index), and per object the pixel count rendered alone."""

    t: np.ndarray
    part: np.ndarray
    alone: np.ndarray


def cast(
    grid: RayGrid,
    parts: PartArrays,
    n_objects: int,
    objects: np.ndarray | None = None,
    t: np.ndarray | None = None,
    count_outside: tuple[int, int] | None = None,
) -> Render:
    """Render ``parts`` (optionally only those of ``objects``) into the z-buffer ``t`` (default empty).

    ``count_outside = (H, W)`` makes ``alone`` count only grid cells whose pixel centre falls
    outside the H x W image (for the parts of objects cut by the image border).
    """
    rows, cols = grid.shape
    depth = np.full((rows, cols), np.inf, np.float32) if t is None else t
    ids = np.full((rows, cols), -1, np.int32)
    alone = np.zeros(n_objects, np.int64)
    rects = grid.rects(parts)
    keep = rects[:, 1] > rects[:, 0]
    keep &= rects[:, 3] > rects[:, 2]
    if objects is not None:
        keep &= np.isin(parts.obj, objects)
    idx = np.flatnonzero(keep)
    if count_outside is not None:
        H, W = count_outside
        u = grid.u0 + grid.stride * np.arange(cols)
        v = grid.v0 + grid.stride * np.arange(rows)
        outside = ~(((v > -0.5) & (v < H - 0.5))[:, None] & ((u > -0.5) & (u < W - 0.5))[None, :])
    for o in np.unique(parts.obj[idx]):
        mine = idx[parts.obj[idx] == o]
        r0, c0 = rects[mine, 0].min(), rects[mine, 2].min()
        r1, c1 = rects[mine, 1].max(), rects[mine, 3].max()
        buf = np.full((r1 - r0, c1 - c0), np.inf, np.float32)
        bid = np.full((r1 - r0, c1 - c0), -1, np.int32)
        for p in mine:
            a0, a1, b0, b1 = rects[p]
            th = grid.hit(parts, int(p), int(a0), int(a1), int(b0), int(b1))
            sub = (slice(a0 - r0, a1 - r0), slice(b0 - c0, b1 - c0))
            closer = th < buf[sub]
            buf[sub] = np.where(closer, th, buf[sub])
            bid[sub][closer] = p
        seen = buf < np.inf
        alone[o] = (
            np.count_nonzero(seen & outside[r0:r1, c0:c1])
            if count_outside is not None
            else np.count_nonzero(seen)
        )
        closer = buf < depth[r0:r1, c0:c1]
        depth[r0:r1, c0:c1][closer] = buf[closer]
        ids[r0:r1, c0:c1][closer] = bid[closer]
    return Render(depth, ids, alone)


def room_exit(grid: RayGrid, half: np.ndarray, centre: np.ndarray, yaw: float) -> np.ndarray:
    """Ray parameter (rows, cols) where rays from inside an upright box (the room) leave it."""
    dx, dy, dz = grid.d
    ca, sa = math.cos(yaw), math.sin(yaw)
    q = grid.origin - centre
    o = (ca * q[0] - sa * q[2], q[1], sa * q[0] + ca * q[2])
    ls = (ca * dx - sa * dz, dy, sa * dx + ca * dz)
    t_hi = np.full(grid.shape, np.inf, np.float32)
    with np.errstate(divide="ignore"):
        for l_, o_, h_ in zip(
            ls, o, half, strict=True
        ):  # exit of each slab: (h - o sign(l)) / |l| (inf if l = 0)
            t_hi = np.minimum(t_hi, (np.float32(h_) - np.float32(o_) * np.sign(l_)) / np.abs(l_))
    return t_hi
