"""One box from many observations of an object: a robust, score-weighted average.

Observations of a static object from many frames scatter (the detector's regression error) and
now and then one is far off (a box fitted to half the object, a neighbour's points). The fused box
is therefore a weighted mean that gives far-off observations less say: iteratively reweighted
with Cauchy weights ``w_i = score_i / (1 + (r_i / scale)^2)`` from a weighted median start
(``robust_mean``), for the centre in metres and the sizes in log space (a size off by a factor
counts the same for a chair and a bed).

The yaw is an axis, not an angle: ``theta`` and ``theta + pi`` are one box, and so are
``(l, w, theta)`` and ``(w, l, theta + pi/2)``. Before averaging, each observation is written in
the form whose yaw is closest to a reference (``align_boxes``), so a bed seen as 2 x 1 m at 0.1 rad
and as 1 x 2 m at 1.67 rad agree; the yaws are then averaged modulo pi, as the angle of the mean
of ``(cos 2 theta, sin 2 theta)``.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.structures.boxes import CENTER, SIZE, THETA, L, W
from a3d.runtime.structures.geometry import canonical_boxes, wrap_half_pi

CENTRE_SCALE_M = 0.15  # residuals of this size halve an observation's weight
LOG_SIZE_SCALE = 0.2  # ... and sizes off by about 22 %
YAW_SCALE = 0.3  # radians
ITERATIONS = 5


def weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per column of ``values`` (N, k), the value at which the cumulative weight reaches half."""
    values = np.asarray(values, np.float64).reshape(len(weights), -1)
    out = np.empty(values.shape[1])
    for j in range(values.shape[1]):
        order = np.argsort(values[:, j], kind="stable")
        cumulative = np.cumsum(weights[order])
        out[j] = values[order[np.searchsorted(cumulative, 0.5 * cumulative[-1])], j]
    return out


def robust_mean(values: np.ndarray, weights: np.ndarray, scale: float) -> np.ndarray:
    """Weighted mean of the rows of ``values`` (N, k) with Cauchy reweighting (module docstring)."""
    values = np.asarray(values, np.float64).reshape(len(weights), -1)
    weights = np.asarray(weights, np.float64)
    mean = weighted_median(values, weights)
    for _ in range(ITERATIONS):
        residual = np.linalg.norm(values - mean, axis=1) / scale
        w = weights / (1.0 + residual**2)
        mean = (w[:, None] * values).sum(axis=0) / w.sum()
    return mean


def align_boxes(boxes: np.ndarray, reference_yaw: float) -> np.ndarray:
    """The same boxes (N, 7), each written as ``(l, w, theta)`` or ``(w, l, theta + pi/2)``,
    whichever has its yaw closer (modulo pi) to ``reference_yaw``; yaws unwrapped to within
    pi/4 of it (so they can be averaged), sizes no longer ordered l >= w."""
    out = np.asarray(boxes, np.float64).reshape(-1, 7).copy()
    turn = np.abs(wrap_half_pi(out[:, THETA] - reference_yaw)) > np.pi / 4
    out[turn, L], out[turn, W] = out[turn, W], out[turn, L].copy()
    out[turn, THETA] += np.pi / 2
    out[:, THETA] = reference_yaw + wrap_half_pi(out[:, THETA] - reference_yaw)
    return out


def mean_axis(yaws: np.ndarray, weights: np.ndarray) -> float:
    """The weighted mean of axes (angles modulo pi): half the angle of the mean of (cos 2t, sin 2t)."""
    c, s = (weights * np.cos(2 * yaws)).sum(), (weights * np.sin(2 * yaws)).sum()
    return 0.5 * float(np.arctan2(s, c))


def fuse_boxes(boxes: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """The fused box (7,) of an object's observations ``boxes`` (N, 7) (one gravity-aligned frame,
    a3d's 7-vectors) weighted by their ``scores`` (N,); canonical (l >= w, yaw in [-pi/2, pi/2])."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 7)
    weights = np.maximum(np.asarray(scores, np.float64), 1e-6)
    reference = float(boxes[int(np.argmax(weights)), THETA])
    for _ in range(ITERATIONS):  # align to the best observation, then to the (reweighted) mean axis
        aligned = align_boxes(boxes, reference)
        residual = np.abs(aligned[:, THETA] - reference) / YAW_SCALE
        reference = mean_axis(aligned[:, THETA], weights / (1.0 + residual**2))
    aligned = align_boxes(boxes, reference)
    centre = robust_mean(aligned[:, CENTER], weights, CENTRE_SCALE_M)
    size = np.exp(robust_mean(np.log(aligned[:, SIZE]), weights, LOG_SIZE_SCALE))
    return canonical_boxes(np.concatenate([centre, size, [reference]])[None])[0]
