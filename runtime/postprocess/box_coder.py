"""Regression targets of the box regressors, and their inverse (numpy, float64).

3D (docs/conventions.md "Regression targets"), proposal P and ground truth G as 7-vectors
``[x, y, z, l, w, h, theta]``::

    dx = (Gx - Px) / Pl   dy = (Gy - Py) / Ph   dz = (Gz - Pz) / Pw
    dl = log(Gl / Pl)     dw = log(Gw / Pw)     dh = log(Gh / Ph)     dtheta = Gtheta

Note the pairing: x with l, y with h, z with w. Decoding inverts it; theta is the regressed
value itself (not wrapped: ``geometry.canonical_boxes`` makes a decoded box canonical).

2D (amodal box regressor): Fast R-CNN deltas on continuous widths ``x2 - x1`` (no "+1"),
``dx = (gcx - pcx) / pw``, ``dy = (gcy - pcy) / ph``, ``dw = log(gw / pw)``, ``dh = log(gh / ph)``.

Decoding clamps the log-scale deltas at ``MAX_LOG_SCALE = log(1000 / 16)`` (as Detectron does)
so that a wild network output gives a large box rather than inf (62.5 times the proposal's size;
encoding is not clamped, and no sensible target comes near it). Inputs that are not finite, or so
large that the result overflows, raise InputError.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from a3d.runtime.errors import InputError

MAX_LOG_SCALE = float(np.log(1000.0 / 16.0))


def _finite(x: np.ndarray, width: int, what: str) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.shape[-1:] != (width,):
        raise InputError(f"{what}: expected shape (..., {width}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what}: NaN or infinite values")
    return arr


def _overflow_checked(fn: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """Run fn with numpy's overflow warnings off and raise InputError if its result is not finite
    (only inputs far out of any sensible range get there)."""

    @functools.wraps(fn)
    def checked(*args: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            out = fn(*args)
        if not np.all(np.isfinite(out)):
            raise InputError(f"{fn.__name__}: the result overflows (boxes or deltas far out of range)")
        return out

    return checked


def _positive(values: np.ndarray, what: str) -> None:
    if not np.all(values > 0):
        raise InputError(f"{what}: sizes must be positive (min {values.min():.3g})")


@_overflow_checked
def encode_3d(proposals: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Deltas (N, 7) that take each proposal box to its ground-truth box."""
    p, g = _finite(proposals, 7, "proposals"), _finite(gt, 7, "gt boxes")
    _positive(p[..., 3:6], "proposals")
    _positive(g[..., 3:6], "gt boxes")
    pl, pw, ph = p[..., 3], p[..., 4], p[..., 5]
    return np.stack(
        [
            (g[..., 0] - p[..., 0]) / pl,
            (g[..., 1] - p[..., 1]) / ph,
            (g[..., 2] - p[..., 2]) / pw,
            np.log(g[..., 3] / pl),
            np.log(g[..., 4] / pw),
            np.log(g[..., 5] / ph),
            np.broadcast_to(g[..., 6], np.broadcast_shapes(p.shape, g.shape)[:-1]),
        ],
        axis=-1,
    )


@_overflow_checked
def decode_3d(proposals: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Boxes (..., 7) from proposals and deltas (broadcast, e.g. (R, 1, 7) with (R, C, 7))."""
    p, d = _finite(proposals, 7, "proposals"), _finite(deltas, 7, "deltas3d")
    pl, pw, ph = p[..., 3], p[..., 4], p[..., 5]
    scale = np.exp(np.minimum(d[..., 3:6], MAX_LOG_SCALE))
    return np.stack(
        [
            p[..., 0] + d[..., 0] * pl,
            p[..., 1] + d[..., 1] * ph,
            p[..., 2] + d[..., 2] * pw,
            pl * scale[..., 0],
            pw * scale[..., 1],
            ph * scale[..., 2],
            np.broadcast_to(d[..., 6], np.broadcast_shapes(p.shape, d.shape)[:-1]),
        ],
        axis=-1,
    )


def _centre_size(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    size = boxes[..., 2:] - boxes[..., :2]
    return boxes[..., :2] + 0.5 * size, size


@_overflow_checked
def encode_2d(rois: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Fast R-CNN deltas (N, 4) = (dx, dy, log dw, log dh) from RoIs to ground-truth boxes."""
    r, g = _finite(rois, 4, "rois"), _finite(gt, 4, "gt boxes2d")
    rc, rs = _centre_size(r)
    gc, gs = _centre_size(g)
    _positive(rs, "rois")
    _positive(gs, "gt boxes2d")
    return np.concatenate([(gc - rc) / rs, np.log(gs / rs)], axis=-1)


@_overflow_checked
def decode_2d(rois: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Boxes [x1, y1, x2, y2] (..., 4) from RoIs and Fast R-CNN deltas (broadcast)."""
    r, d = _finite(rois, 4, "rois"), _finite(deltas, 4, "deltas2d")
    rc, rs = _centre_size(r)
    centre = rc + d[..., :2] * rs
    half = 0.5 * rs * np.exp(np.minimum(d[..., 2:], MAX_LOG_SCALE))
    return np.concatenate([centre - half, centre + half], axis=-1)
