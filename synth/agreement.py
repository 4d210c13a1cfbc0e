"""Does a rendered frame's ground truth agree with its pixels? The generator's consistency checks.

Three properties every frame must have (README "Synthetic scenes"): the sensed depth of each
annotated object's mask lies in its amodal 3D box grown by 5 cm (>= 95 % of the pixels with
valid depth), its amodal 2D box contains its visible-mask box, and R_tilt levels the floor.
``tests/test_synth.py`` asserts them on a few frames, ``bench/synth_agreement.py`` over a set.
"""

from __future__ import annotations

import math

import numpy as np

from a3d.runtime.structures.geometry import backproject
from a3d.synth.scene import SynthFrame


def box_local(points_cam: np.ndarray, box3d: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) in the box's own axes (x along l, y along h, z along w), by
    docs/conventions.md's box parametrisation: centre in the camera frame, yaw in the tilt frame."""
    p = points_cam @ R_tilt.T - R_tilt @ box3d[:3]
    c, s = math.cos(box3d[6]), math.sin(box3d[6])
    return np.stack([c * p[:, 0] - s * p[:, 2], p[:, 1], s * p[:, 0] + c * p[:, 2]], axis=1)


def in_box(local: np.ndarray, box3d: np.ndarray, margin: float) -> np.ndarray:
    """(N,) bool: box-local points within the box grown by ``margin`` metres on every side."""
    half = np.array([box3d[3], box3d[5], box3d[4]]) / 2 + margin
    return np.all(np.abs(local) <= half, axis=1)


def sensed_inside_shares(frame: SynthFrame, margin: float = 0.05) -> list[tuple[str, float, float]]:
    """(class, median true depth, share of valid-depth mask pixels in the box + margin) per
    annotated object that has any valid sensed depth."""
    rows = []
    for k, box in enumerate(frame.gt.boxes3d):
        v, u = np.nonzero((frame.instances == frame.gt.instance_ids[k]) & (frame.depth > 0))
        if len(u):
            local = box_local(backproject(u, v, frame.depth[v, u], frame.intrinsics), box, frame.R_tilt)
            share = float(in_box(local, box, margin).mean())
            rows.append((frame.gt.classes[k], float(np.median(frame.depth_exact[v, u])), share))
    return rows


def exact_depth_in_boxes(frame: SynthFrame, margin: float = 0.001) -> bool:
    """Every mask pixel's noise-free depth lies in its object's box (grown by ``margin``)."""
    for k, box in enumerate(frame.gt.boxes3d):
        v, u = np.nonzero(frame.instances == frame.gt.instance_ids[k])
        local = box_local(backproject(u, v, frame.depth_exact[v, u], frame.intrinsics), box, frame.R_tilt)
        if not in_box(local, box, margin).all():
            return False
    return True


def amodal_contains_visible(frame: SynthFrame, tol: float = 0.5) -> bool:
    """Every amodal 2D box contains its visible-mask box (to ``tol`` px: the mask box is the
    pixels' exact extent, the amodal box the projection of the 3D box)."""
    vis, amo = frame.gt.boxes2d_visible, frame.gt.boxes2d_amodal
    return bool(np.all(amo[:, :2] <= vis[:, :2] + tol) and np.all(amo[:, 2:] >= vis[:, 2:] - tol))


def floor_height_spread(frame: SynthFrame) -> float:
    """Spread (max - min, metres) of the noise-free floor points' tilt-frame y: 0 when R_tilt
    levels the floor exactly; NaN when no floor is in view."""
    v, u = np.nonzero(frame.floor)
    if not len(u):
        return math.nan
    y = (backproject(u, v, frame.depth_exact[v, u], frame.intrinsics) @ frame.R_tilt.T)[:, 1]
    return float(y.max() - y.min())
