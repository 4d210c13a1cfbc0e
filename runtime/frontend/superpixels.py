"""Over-segmentation of an RGB-D frame into superpixels: the leaves of the proposal hierarchy.

Why this design: the runtime has no ximgproc (no SLIC, no graph segmentation), but OpenCV's
marker watershed is fast C++. `cv2.watershed` grows seeded regions in order of the colour
difference (max over the 3 channels) between neighbouring pixels, a minimum spanning forest of
the 4-connected pixel graph, so its boundaries snap to colour edges. Depth discontinuities are
not colours; they enter as *barriers*: their pixels are painted in a black/white checkerboard,
so that crossing a barrier (2 px or wider) costs the maximum step of 255 and no region leaks
through it before everything else is flooded.

Seeds sit on a regular grid (about `n_segments` of them), each moved to the pixel of its cell
with the weakest colour gradient off the barriers, so that superpixels start inside surfaces.
After this first flood the barrier pixels are cleared and flooded again from the superpixels
around them by lightness and depth: a thin part in front of a wall (a chair leg, a lamp's pole)
then joins the part it is attached to at the same depth, not the wall. The last pixels left
(watershed lines) join their most similar neighbouring superpixel.

Everything here works at the caller's (reduced) working resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SuperpixelConfig:
    """Over-segmentation parameters (working-resolution pixels).

    `n_segments`: number of grid seeds (about the number of superpixels; 1000 at half
    resolution are ~240 full-resolution pixels each, fine enough for objects of a few hundred).
    `depth_jump`: relative depth step |dz| / z between 4-neighbours that marks a depth edge.
    `barrier_width`: the depth edges are dilated to this width (>= 2 to be leak-proof).
    `depth_phase`: radians per unit log depth of the (cos, sin) depth code that re-floods the
    barriers (8: a 4 % step is a 40-level step, a 2x step about 250 levels of 255).
    `depth_weight`: Lab units per unit of log depth when the last (watershed-line) pixels pick
    their superpixel (1000: a 4 % depth step weighs like 40 Lab units).
    `smooth`: sigma (pixels) of the Gaussian that calms sensor noise before flooding.
    """

    n_segments: int = 1000
    depth_jump: float = 0.04
    barrier_width: int = 2
    depth_phase: float = 8.0
    depth_weight: float = 1000.0
    smooth: float = 1.0


def depth_edges(log_depth: np.ndarray, valid: np.ndarray, config: SuperpixelConfig) -> np.ndarray:
    """(h, w) bool: the pixels on either side of a depth discontinuity, a relative step
    |dz| / z > `config.depth_jump` between 4-neighbours with known depth. `log_depth` (h, w)
    float32 is log(z) (so steps are relative), `valid` (h, w) bool where the depth is known.

    Surface creases are not barriers: normals from sensor depth are too noisy at a few pixels'
    scale (far surfaces fill with false creases); they act in the grouping instead."""
    step = np.log1p(config.depth_jump)
    edges = np.zeros(log_depth.shape, dtype=bool)
    dzx = (np.abs(np.diff(log_depth, axis=1)) > step) & valid[:, 1:] & valid[:, :-1]
    dzy = (np.abs(np.diff(log_depth, axis=0)) > step) & valid[1:, :] & valid[:-1, :]
    edges[:, 1:] |= dzx
    edges[:, :-1] |= dzx
    edges[1:, :] |= dzy
    edges[:-1, :] |= dzy
    return edges


def oversegment(
    lab: np.ndarray, log_depth: np.ndarray, barrier: np.ndarray, config: SuperpixelConfig
) -> np.ndarray:
    """Grid-seeded watershed of a Lab image with depth barriers (see the module docstring).

    `lab` (h, w, 3) uint8 (OpenCV Lab), `log_depth` (h, w) float32 (0 where unknown), `barrier`
    (h, w) bool (depth_edges). Returns (h, w) int32 labels 0..N-1, every label present, every
    pixel labelled; images thinner than 3 pixels are one superpixel.
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
    # Barrier pixels were flooded by colour-blind rules: clear them (and the -1 watershed
    # lines) and flood them again by lightness and depth.
    markers[barrier | (markers < 0)] = 0
    phase = config.depth_phase * log_depth
    depth_image = np.stack([lab[..., 0], 128 + 127 * np.cos(phase), 128 + 127 * np.sin(phase)], axis=2)
    cv2.watershed(depth_image.astype(np.uint8), markers)
    features = np.stack([*np.moveaxis(lab, 2, 0), config.depth_weight * log_depth]).astype(np.float32)
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
    labelled 4-neighbour with the closest features (L1 over the (C, h, w) planes `features`), in
    place; repeated from the outside in until all are labelled, so every superpixel stays
    connected."""
    if (markers <= 0).all():
        markers[:] = 1
        return
    h, w = markers.shape
    labels = markers.ravel()  # a view: writes go to markers
    planes = features.reshape(features.shape[0], h * w)
    todo = np.flatnonzero(labels <= 0)
    ys, xs = np.divmod(todo, w)
    # Flat index of each 4-neighbour, the pixel itself where the neighbour is off the image.
    neighbours = np.stack(
        [
            np.where(xs > 0, todo - 1, todo),
            np.where(xs < w - 1, todo + 1, todo),
            np.where(ys > 0, todo - w, todo),
            np.where(ys < h - 1, todo + w, todo),
        ]
    )
    own = planes[:, todo]
    cost = np.zeros(neighbours.shape, np.float32)
    for plane, mine in zip(planes, own, strict=True):
        cost += np.abs(plane[neighbours] - mine)
    while todo.size:
        candidate = labels[neighbours]
        choice = np.where(candidate > 0, cost, np.inf).argmin(axis=0)
        label = np.take_along_axis(candidate, choice[None], axis=0)[0]
        done = label > 0
        labels[todo[done]] = label[done]
        todo, neighbours, cost = todo[~done], neighbours[:, ~done], cost[:, ~done]


def _compact_labels(markers: np.ndarray) -> np.ndarray:
    """Relabel positive marker ids to 0..N-1 (ids of seeds lost to the border disappear)."""
    present = np.zeros(int(markers.max()) + 1, bool)
    present[markers.ravel()] = True
    lut = (np.cumsum(present) - 1).astype(np.int32)
    return lut[markers]
