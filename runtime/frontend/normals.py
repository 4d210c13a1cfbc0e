"""Surface normals from a metric depth map, for gravity estimation and proposal features.

Normals are computed on a grid of every `step`-th pixel: the samples are back-projected to a
camera-frame point map (x right, y down, z forward, metres), the point map is smoothed by a box
filter over valid samples only, and the normal is the cross product of its central differences
along the rows and columns. A box mean of points on a plane stays on that plane, so the normals
of planar surfaces are exact whatever the window. Windows that straddle a depth discontinuity
(a relative step larger than `max_jump` between neighbouring samples) or hold too few valid
samples get no normal (0): their point mix is not a surface.

Normals are unit float32 vectors oriented toward the camera (n . p < 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.structures.geometry import CameraLike, backproject


@dataclass(frozen=True)
class NormalConfig:
    """`step`: sampling stride (pixels); `window`: box side (samples) of the point-map smoothing;
    `max_jump`: relative depth step between neighbouring samples taken as a discontinuity;
    `min_valid_fraction`: least fraction of valid samples in a window."""

    step: int = 4
    window: int = 5
    max_jump: float = 0.08
    min_valid_fraction: float = 0.5


@dataclass(frozen=True)
class NormalGrid:
    """Normals on the sample grid: sample (i, j) is pixel (u, v) = (cols[j], rows[i]).

    `normals` (h, w, 3) float32 unit vectors, 0 where `valid` is False.
    """

    normals: np.ndarray
    valid: np.ndarray
    rows: np.ndarray
    cols: np.ndarray


def normal_grid(depth: np.ndarray, K: CameraLike, config: NormalConfig = NormalConfig()) -> NormalGrid:
    """Normals at every `config.step`-th pixel (block centres) of an (H, W) metric depth map."""
    if depth.ndim != 2:
        raise ValueError(f"normals: expected an (H, W) depth map, got shape {depth.shape}")
    s = max(1, int(config.step))
    rows = np.arange(s // 2, depth.shape[0], s)
    cols = np.arange(s // 2, depth.shape[1], s)
    z = np.ascontiguousarray(depth[s // 2 :: s, s // 2 :: s], dtype=np.float32)
    h, w = z.shape
    valid = z > 0
    normals = np.zeros((h, w, 3), np.float32)
    if h < 3 or w < 3:
        return NormalGrid(normals, np.zeros_like(valid), rows, cols)
    # Ray directions at z = 1 of the sample columns / rows; points are ray * z (0 without depth).
    xn = backproject(cols, 0.0, 1.0, K)[:, 0].astype(np.float32)
    yn = backproject(0.0, rows, 1.0, K)[:, 1].astype(np.float32)
    points = (xn[None, :] * z, yn[:, None] * z, z)

    # Samples on either side of a depth discontinuity; no window may contain one.
    jump = np.zeros_like(valid)
    for axis in (0, 1):
        a = np.swapaxes(z, 0, axis)
        both = (a[1:] > 0) & (a[:-1] > 0)
        big = both & (np.abs(a[1:] - a[:-1]) > config.max_jump * np.minimum(a[1:], a[:-1]))
        j = np.swapaxes(jump, 0, axis)
        j[1:] |= big
        j[:-1] |= big
    k = max(1, int(config.window))
    box = (k, k)

    def box_sum(image: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(image, -1, box, normalize=False, borderType=cv2.BORDER_CONSTANT)

    weight = box_sum(valid.astype(np.float32))
    inv = 1.0 / np.maximum(weight, 1.0)
    smooth = [box_sum(c) * inv for c in points]
    near_jump = cv2.dilate(jump.view(np.uint8), np.ones(box, np.uint8)).astype(bool)
    support = (weight >= config.min_valid_fraction * k * k) & ~near_jump

    # Central differences on the interior: a along rows (down), b along columns (right);
    # n = a x b faces the camera for a surface seen from the front.
    a = [c[2:, 1:-1] - c[:-2, 1:-1] for c in smooth]
    b = [c[1:-1, 2:] - c[1:-1, :-2] for c in smooth]
    n = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    norm = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    ok = (
        support[1:-1, 1:-1]
        & support[1:-1, 2:]
        & support[1:-1, :-2]
        & support[2:, 1:-1]
        & support[:-2, 1:-1]
        & valid[1:-1, 1:-1]
        & (norm > 0)
    )
    # Orient toward the camera (n . p < 0, p the sample's own point) and normalise.
    facing = n[0] * points[0][1:-1, 1:-1] + n[1] * points[1][1:-1, 1:-1] + n[2] * points[2][1:-1, 1:-1]
    scale = np.where(ok, np.where(facing > 0, -1.0, 1.0) / np.maximum(norm, 1e-30), 0.0).astype(np.float32)
    for c in range(3):
        normals[1:-1, 1:-1, c] = n[c] * scale
    valid_out = np.zeros_like(valid)
    valid_out[1:-1, 1:-1] = ok
    return NormalGrid(normals, valid_out, rows, cols)


def surface_normals(depth: np.ndarray, K: CameraLike, config: NormalConfig = NormalConfig()) -> np.ndarray:
    """(H, W) metric depth -> (H, W, 3) float32 unit normals toward the camera, 0 where invalid.

    Each pixel with depth takes the normal of the grid sample at the centre of its step x step
    block; pixels without depth get 0.
    """
    grid = normal_grid(depth, K, config)
    s = max(1, int(config.step))
    h, w = depth.shape
    up = cv2.resize(grid.normals, (grid.cols.size * s, grid.rows.size * s), interpolation=cv2.INTER_NEAREST)
    # A last partial block whose centre lies outside the image copies its neighbour block.
    pad_b, pad_r = max(0, h - up.shape[0]), max(0, w - up.shape[1])
    if pad_b or pad_r:
        up = cv2.copyMakeBorder(up, 0, pad_b, 0, pad_r, cv2.BORDER_REPLICATE)
    up = np.ascontiguousarray(up[:h, :w])
    up[depth <= 0] = 0
    return up
