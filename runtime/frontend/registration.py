"""Depth registration: a depth map seen by the depth camera, redrawn as the colour camera sees it.

Many recordings (RealSense SDK bags, Kinect v2 / Azure Kinect raw streams, bags without an
``aligned_depth_to_color`` topic) hold depth in the depth camera's own frame: another pinhole,
centimetres beside the colour camera. a3d needs depth on the colour pixels, so every source whose
depth is not registered goes through ``register_depth``.

How: the depth map is a mesh (two triangles per 2 x 2 block of valid pixels) carried into the colour
camera by the extrinsics and rasterised there, interpolating inverse depth (exact for planes, which
a per-pixel splat is not: on a slanted floor it is off by the depth change of a pixel, centimetres
far away). A triangle whose corners' depths differ by more than ``max_step`` (relative; 3 %: 6 cm at
2 m, more than a floor's step between neighbouring pixels of a 320-pixel-wide depth camera out to 8
m) spans an occlusion edge and is dropped, so a hole the colour camera sees behind a foreground edge
stays a hole instead of being bridged. Where several surfaces land on one pixel the nearest wins (a
z-buffer). Missing depth stays 0, and so does every pixel no triangle covers: an isolated valid
depth pixel is dropped rather than splatted to the nearest colour pixel, which on anything but a
fronto-parallel surface puts the wrong depth there (off by up to a pixel's depth change, and most
such pixels lie on edges).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.structures.geometry import Intrinsics, check_rotation

NEAR = 0.05  # metres; points closer to the colour camera than this are dropped
MAX_STEP = 0.03  # largest relative depth difference across one triangle (occlusion edges exceed it)
_CHUNK = 1 << 18  # triangles rasterised at once (bounds the memory of one step)


@dataclass(frozen=True)
class DepthToColor:
    """What registration needs: the depth camera's intrinsics and the rigid transform from the
    depth camera's frame to the colour camera's, ``p_color = R @ p_depth + t`` (metres)."""

    depth_intrinsics: Intrinsics
    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,)

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", check_rotation(np.asarray(self.R, np.float64), "extrinsics rotation"))
        t = np.asarray(self.t, np.float64).reshape(-1)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise InputError(f"extrinsics translation: expected 3 finite numbers, got {self.t!r:.80}")
        object.__setattr__(self, "t", t)


def register_depth(
    depth: np.ndarray,
    calibration: DepthToColor,
    color_intrinsics: Intrinsics,
    color_size: tuple[int, int],
    max_step: float = MAX_STEP,
) -> np.ndarray:
    """(H, W) float32 metres on the colour pixels of ``depth`` (h, w) float metres in the depth
    camera (0 = missing); see the module docstring."""
    H, W = color_size
    z = np.asarray(depth, np.float64)
    u, v, zc = _to_color(z, calibration, color_intrinsics)
    out = np.full(H * W, np.inf)
    _rasterise(u, v, zc, z, (H, W), max_step, out)
    out[~np.isfinite(out)] = 0.0
    return out.reshape(H, W).astype(np.float32)


def _to_color(
    z: np.ndarray, calibration: DepthToColor, K: Intrinsics
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour-image coordinates (u, v) and colour-camera depth of every depth pixel (NaN where
    the pixel has no depth or lands behind the near plane)."""
    h, w = z.shape
    kd = calibration.depth_intrinsics
    rows, cols = np.mgrid[0:h, 0:w]
    points = np.stack([(cols - kd.cx) / kd.fx * z, (rows - kd.cy) / kd.fy * z, z], axis=-1)
    moved = points @ calibration.R.T + calibration.t
    zc = moved[..., 2]
    ok = (z > 0) & (zc > NEAR)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(ok, K.fx * moved[..., 0] / zc + K.cx, np.nan)
        v = np.where(ok, K.fy * moved[..., 1] / zc + K.cy, np.nan)
    return u, v, np.where(ok, zc, np.nan)


def _rasterise(
    u: np.ndarray,
    v: np.ndarray,
    zc: np.ndarray,
    z: np.ndarray,
    size: tuple[int, int],
    max_step: float,
    out: np.ndarray,
) -> None:
    """Draw the depth mesh's triangles into the flat z-buffer ``out``."""
    H, W = size
    corners = ((0, 0), (0, 1), (1, 0)), ((0, 1), (1, 1), (1, 0))
    h, w = z.shape
    for tri in corners:
        us = np.stack([u[dr : h - 1 + dr, dc : w - 1 + dc].ravel() for dr, dc in tri])
        vs = np.stack([v[dr : h - 1 + dr, dc : w - 1 + dc].ravel() for dr, dc in tri])
        zs = np.stack([zc[dr : h - 1 + dr, dc : w - 1 + dc].ravel() for dr, dc in tri])
        src = np.stack([z[dr : h - 1 + dr, dc : w - 1 + dc].ravel() for dr, dc in tri])
        with np.errstate(invalid="ignore"):
            keep = np.isfinite(us).all(0) & (src.max(0) <= (1 + max_step) * src.min(0))
        us, vs, zs = us[:, keep], vs[:, keep], zs[:, keep]
        for start in range(0, us.shape[1], _CHUNK):
            part = slice(start, start + _CHUNK)
            _draw_triangles(us[:, part], vs[:, part], 1.0 / zs[:, part], (H, W), out)


def _draw_triangles(
    us: np.ndarray, vs: np.ndarray, inv_z: np.ndarray, size: tuple[int, int], out: np.ndarray
) -> None:
    """Rasterise triangles (3, N) at the integer pixel centres they contain, interpolating
    inverse depth with barycentric weights; keep the nearest in ``out``."""
    H, W = size
    area = (us[1] - us[0]) * (vs[2] - vs[0]) - (us[2] - us[0]) * (vs[1] - vs[0])
    good = np.abs(area) > 1e-12
    us, vs, inv_z, area = us[:, good], vs[:, good], inv_z[:, good], area[good]
    c0 = np.ceil(us.min(0)).astype(np.int64)
    r0 = np.ceil(vs.min(0)).astype(np.int64)
    c1 = np.floor(us.max(0)).astype(np.int64)
    r1 = np.floor(vs.max(0)).astype(np.int64)
    span_c, span_r = c1 - c0 + 1, r1 - r0 + 1
    if span_c.size == 0:
        return
    for dr in range(int(span_r.max())):
        for dc in range(int(span_c.max())):
            sel = np.flatnonzero((span_r > dr) & (span_c > dc))
            px, py = (c0[sel] + dc).astype(np.float64), (r0[sel] + dr).astype(np.float64)
            tu, tv = us[:, sel], vs[:, sel]
            b0 = ((tu[1] - px) * (tv[2] - py) - (tu[2] - px) * (tv[1] - py)) / area[sel]
            b1 = ((tu[2] - px) * (tv[0] - py) - (tu[0] - px) * (tv[2] - py)) / area[sel]
            b2 = 1.0 - b0 - b1
            eps = -1e-9
            inside = (b0 >= eps) & (b1 >= eps) & (b2 >= eps) & (px >= 0) & (px < W) & (py >= 0) & (py < H)
            inv = b0 * inv_z[0, sel] + b1 * inv_z[1, sel] + b2 * inv_z[2, sel]
            inside &= inv > 0
            index = (py[inside] * W + px[inside]).astype(np.int64)
            np.minimum.at(out, index, 1.0 / inv[inside])
