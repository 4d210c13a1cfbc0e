"""Over-segmentation of an RGB-D frame into superpixels: the leaves of the proposal hierarchy.

Why this design: the runtime has no ximgproc (no SLIC, no graph segmentation), but OpenCV's
marker watershed is fast C++. `cv2.watershed` grows seeded regions in order of the colour
difference (max over the 3 channels) between neighbouring pixels, i.e. a minimum spanning forest
of the 4-connected pixel graph, so its boundaries snap to colour edges. Depth discontinuities
and surface creases are not colours; they enter as *barriers*: the pixels on a geometric edge
are painted in a black/white checkerboard, so that crossing a barrier (2 px or wider) costs the
maximum step of 255 and no region leaks through it before everything else is flooded.

Seeds sit on a regular grid (about `n_segments` of them), each moved to the pixel with the
weakest colour gradient of its cell off the barriers, so that superpixels start inside surfaces.
After flooding, the barrier pixels are cleared and re-assigned, from their borders inward, to the
neighbouring superpixel most similar in colour and depth.
Everything here works at the caller's (reduced) working resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SuperpixelConfig:
    """Over-segmentation parameters (working-resolution pixels).

    `n_segments`: number of grid seeds (about the number of superpixels).
    `depth_jump`: relative depth step |dz| / z between 4-neighbours that marks a depth edge.
    `crease`: change of the unit surface normal |dn| between pixels two apart that marks a crease
    (0.35 is about 20 degrees).
    `barrier_width`: width in pixels of the painted geometric barriers (>= 2 to be leak-proof).
    `depth_weight`: Lab units per unit of log depth when barrier pixels pick their superpixel
    (1000: a 4 % depth step weighs like 40 Lab units) when watershed-line pixels pick theirs.
    `depth_phase`: radians per unit log depth of the (cos, sin) depth code that re-floods the
    barriers (8: a 4 % step is a 40-level step, a 2x step about 250 levels).
    """

    n_segments: int = 1000
    depth_jump: float = 0.04
    crease: float = 100.0
    barrier_width: int = 2
    depth_weight: float = 1000.0
    depth_phase: float = 8.0
    smooth: float = 1.0


def geometric_edges(
    log_depth: np.ndarray,
    valid: np.ndarray,
    normals: np.ndarray,
    normal_ok: np.ndarray,
    config: SuperpixelConfig,
) -> np.ndarray:
    """(h, w) bool: pixels on a depth discontinuity or a surface crease.

    `log_depth` (h, w) float32 is log(z) (so steps are relative), `valid` (h, w) bool where the
    depth is known; `normals` (h, w, 3) unit vectors, `normal_ok` where they are defined.
    Unknown depth or normals never make edges.
    """
    jump = np.zeros(log_depth.shape, dtype=bool)
    dzx = np.abs(np.diff(log_depth, axis=1)) > np.log1p(config.depth_jump)
    dzx &= valid[:, 1:] & valid[:, :-1]
    dzy = np.abs(np.diff(log_depth, axis=0)) > np.log1p(config.depth_jump)
    dzy &= valid[1:, :] & valid[:-1, :]
    jump[:, 1:] |= dzx
    jump[:, :-1] |= dzx
    jump[1:, :] |= dzy
    jump[:-1, :] |= dzy
    # Normal change over a 2-pixel baseline (central differences), as a chord length.
    n = normals.astype(np.float32)
    gx = n[:, 2:] - n[:, :-2]
    gy = n[2:, :] - n[:-2, :]
    crease = np.zeros(log_depth.shape, dtype=bool)
    crease[:, 1:-1] |= (np.einsum("ijk,ijk->ij", gx, gx) > config.crease**2) & normal_ok[:, 2:] & normal_ok[:, :-2]
    crease[1:-1, :] |= (np.einsum("ijk,ijk->ij", gy, gy) > config.crease**2) & normal_ok[2:, :] & normal_ok[:-2, :]
    return jump | crease


def oversegment(
    lab: np.ndarray, log_depth: np.ndarray, barrier: np.ndarray, config: SuperpixelConfig
) -> np.ndarray:
    """Grid-seeded watershed of a Lab image with geometric barriers.

    `lab` (h, w, 3) uint8 (OpenCV Lab), `log_depth` (h, w) float32 (0 where unknown), `barrier`
    (h, w) bool. Returns (h, w) int32 labels 0..N-1, every label present, every pixel labelled.
    """
    h, w = barrier.shape
    if h < 3 or w < 3:
        return np.zeros((h, w), np.int32)
    if config.barrier_width > 1:
        kernel = np.ones((config.barrier_width, config.barrier_width), np.uint8)
        barrier = cv2.dilate(barrier.view(np.uint8), kernel).astype(bool)
    if config.smooth > 0:
        lab = cv2.GaussianBlur(lab, (0, 0), config.smooth)
    image = lab.copy()
    checker = ((np.indices((h, w)).sum(0) & 1) * 255).astype(np.uint8)
    image[barrier] = 128
    image[barrier, 0] = checker[barrier]

    seeds = _grid_seeds(lab, barrier, config.n_segments)
    markers = seeds.copy()
    cv2.watershed(image, markers)
    # Barrier pixels were flooded by colour-blind rules: clear them and flood them again, now by
    # lightness and depth, so that thin parts (legs, poles) join the surface they are attached
    # to rather than the one behind them.
    markers[barrier] = 0
    phase = config.depth_phase * log_depth
    depth_image = np.stack([lab[..., 0], 128 + 127 * np.cos(phase), 128 + 127 * np.sin(phase)], axis=2)
    cv2.watershed(depth_image.astype(np.uint8), markers)
    features = np.concatenate([lab.astype(np.float32), config.depth_weight * log_depth[..., None]], axis=2)
    _fill_unlabelled(markers, features)
    return _compact_labels(markers)


def _grid_seeds(lab: np.ndarray, barrier: np.ndarray, n_segments: int) -> np.ndarray:
    """int32 marker image with one seed per grid cell (1..n) at the cell's weakest-gradient pixel,
    never on a barrier (a seed there would flood both sides) nor on the 1-pixel image border
    (cv2.watershed overwrites it); cells without such a pixel get no seed."""
    h, w = barrier.shape
    grad = np.zeros((h, w), np.float32)
    for c in range(3):
        gx = cv2.Sobel(lab[..., c], cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(lab[..., c], cv2.CV_32F, 0, 1, ksize=3)
        grad += np.abs(gx) + np.abs(gy)
    grad[barrier] = np.inf
    grad[[0, -1], :] = np.inf
    grad[:, [0, -1]] = np.inf
    cell = max(2, round(np.sqrt(h * w / max(1, n_segments))))
    ny, nx = -(-h // cell), -(-w // cell)
    padded = np.full((ny * cell, nx * cell), np.inf, np.float32)
    padded[:h, :w] = grad
    blocks = padded.reshape(ny, cell, nx, cell).transpose(0, 2, 1, 3).reshape(ny, nx, cell * cell)
    best = blocks.argmin(axis=2)
    ok = np.isfinite(np.take_along_axis(blocks, best[..., None], axis=2)[..., 0])
    by, bx = np.divmod(best, cell)
    ys = (np.arange(ny)[:, None] * cell + by)[ok]
    xs = (np.arange(nx)[None, :] * cell + bx)[ok]
    markers = np.zeros((h, w), np.int32)
    markers[ys, xs] = np.arange(1, ys.size + 1, dtype=np.int32)
    return markers


def _fill_unlabelled(markers: np.ndarray, features: np.ndarray) -> None:
    """Give every unlabelled pixel (<= 0: watershed lines, cleared barriers) the label of its
    labelled 4-neighbour with the closest features (L1), in place; repeated from the outside in
    until all are labelled, so every superpixel stays connected."""
    if (markers <= 0).all():
        markers[:] = 1
        return
    h, w = markers.shape
    ys, xs = np.nonzero(markers <= 0)
    # Neighbour d of pixel (y, x) is padded[y + dy + 1, x + dx + 1]; the padding is unlabelled.
    shifts = ((1, 0), (1, 2), (0, 1), (2, 1))
    fpad = np.pad(features, ((1, 1), (1, 1), (0, 0)), mode="edge")
    own = features[ys, xs]
    cost = np.stack([np.abs(fpad[ys + y, xs + x] - own).sum(axis=1) for y, x in shifts])
    lpad = np.pad(markers, 1)
    while ys.size:
        neighbours = np.stack([lpad[ys + y, xs + x] for y, x in shifts])
        choice = np.where(neighbours > 0, cost, np.inf).argmin(axis=0)
        label = np.take_along_axis(neighbours, choice[None], axis=0)[0]
        done = label > 0
        lpad[ys[done] + 1, xs[done] + 1] = label[done]
        ys, xs, cost = ys[~done], xs[~done], cost[:, ~done]
    markers[:] = lpad[1:-1, 1:-1]


def _compact_labels(markers: np.ndarray) -> np.ndarray:
    """Relabel positive marker ids to 0..N-1 (ids of seeds lost to the border disappear)."""
    present = np.zeros(int(markers.max()) + 1, bool)
    present[markers.ravel()] = True
    lut = (np.cumsum(present) - 1).astype(np.int32)
    return lut[markers]
