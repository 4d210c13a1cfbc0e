"""A room of textured planes, rendered (colour and depth) from any pose: what image features need.

Why: a3d-synth's rooms are plain-coloured, and relocalisation by image features
(a3d.runtime.mapping.relocalise) needs the texture real rooms have. Here the floor and three walls
carry blotchy random texture, ray-cast exactly: the true pose of every view is known.
"""

from __future__ import annotations

import cv2
import numpy as np

from a3d.runtime.structures.geometry import Intrinsics

SIZE = (240, 320)
INTRINSICS = Intrinsics(fx=260.0, fy=260.0, cx=159.5, cy=119.5)
# planes as (normal axis, offset along it, the two in-plane axes): camera-style world, y down
PLANES = ((1, 1.3), (2, 4.0), (0, -2.5), (0, 2.5))  # floor, far wall, left wall, right wall
TEXELS_PER_M = 120


def _texture(seed: int) -> np.ndarray:
    """A (1200, 1200) uint8 texture of blotches and edges at several scales, tiled at TEXELS_PER_M."""
    rng = np.random.default_rng(seed)
    texture = np.zeros((1200, 1200), np.float32)
    for cells, weight in ((12, 0.5), (40, 0.3), (150, 0.2)):
        noise = rng.uniform(0, 255, (cells, cells)).astype(np.float32)
        texture += weight * cv2.resize(noise, (1200, 1200), interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(texture, (0, 0), 1.0).astype(np.uint8)


def render(pose: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(colour (H, W, 3) uint8 BGR, depth (H, W) float32 metres) of the room seen by a camera at
    ``pose`` (camera to world, 4 x 4)."""
    height, width = SIZE
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    x, y = (u - INTRINSICS.cx) / INTRINSICS.fx, (v - INTRINSICS.cy) / INTRINSICS.fy
    rays = np.stack([x, y, np.ones_like(u)], -1)
    directions = rays @ pose[:3, :3].T
    origin = pose[:3, 3]
    nearest = np.full(SIZE, np.inf)
    gray = np.zeros(SIZE, np.uint8)
    for index, (axis, offset) in enumerate(PLANES):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset - origin[axis]) / directions[..., axis]
        hit = (t > 0) & (t < nearest)
        points = origin + directions * t[..., None]
        a, b = (k for k in range(3) if k != axis)
        texture = _texture(seed + index)
        rows, cols = (np.mod(np.floor(points[..., k] * TEXELS_PER_M), 1200).astype(int) for k in (a, b))
        gray = np.where(hit, texture[rows, cols], gray)
        nearest = np.where(hit, t, nearest)
    depth = np.where(np.isfinite(nearest), nearest, 0).astype(np.float32)  # rays of unit z: t is the depth
    return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR), depth
