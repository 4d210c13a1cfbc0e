"""How much of the depth inside a detection's 2D box its 3D box holds: evidence for its score.

Why: a detection's 3D box is inferred from a 2D box, its lifted centre and the class's size;
where the lifting took the wrong depth layer (a 2D detector's box around a chair, whose middle
shows the wall through its back; a painting a detector calls a television) the box floats in
front of or behind the object, and nothing the network scores looks at where it ended up. The
depth does: of the pixels of the 2D box that have depth, the share whose 3D points lie in the
3D box (grown by ``MARGIN_M`` for the sensor's noise) is its ``support``. A right detection holds
its object's pixels, which fill a good part of its 2D box; a misplaced one holds next to none.
The support moves the score in log-odds, as the detector's and the network's opinions are fused
(a3d.runtime.postprocess.fuse):
``sigmoid(logit(score) + SUPPORT_WEIGHT * (support - SUPPORT_REFERENCE))``.

``SUPPORT_WEIGHT`` was chosen on a3d-synth frames of a seed no other benchmark uses (2031, not the
held-out 2027) and ``SUPPORT_REFERENCE`` on the real frames, so that a detection scoring 0.5
stays at least as likely right as wrong there (docs/real-rooms.md measures both). It is part of
the pipelines with a 2D detector (its boxes are the ones lifted from a guessed depth layer), on
the frames where the detector ran (where it failed, the frame keeps the network's own scores);
it costs about 8 ms a frame, which the network alone (`live`, the fast choice) does not pay.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from a3d.runtime.postprocess.score_calibration import SCORE_EPS
from a3d.runtime.structures.geometry import (
    CameraLike,
    backproject,
    evenly_spread,
    pixel_window,
    points_in_box,
)

SUPPORT_WEIGHT = 2.0
SUPPORT_REFERENCE = 0.6
MARGIN_M = 0.05
OBJECT_POINTS = 1500  # of a 2D box's samples, spread over it: an object's surface to a centimetre, quickly
FLOOR_GAP_M = 0.03  # samples this close to the floor are the floor's, not an object's
STRIDE = 2  # every 2nd pixel of every 2nd row: the share, at a quarter of the cost
MIN_SCORE = 0.01  # below it no evidence matters (moved by at most 0.8 in log-odds, it stays under 0.022)


@dataclass(frozen=True, eq=False)
class SampledDepth:
    """A frame's depth with its samples (every ``STRIDE``-th pixel of every ``STRIDE``-th row)
    back-projected to tilt-frame points once: what the depth steps (5, 7 to 10) count over. Each 2D
    box's samples are gathered once a frame (``box_points``), however many steps ask for them."""

    depth: np.ndarray  # (H, W) metres, 0 where missing
    K: CameraLike
    R_tilt: np.ndarray  # (3, 3)
    points: np.ndarray  # (h, w, 3) the samples' tilt-frame points
    valid: np.ndarray  # (h, w) bool: the sample has depth
    held: dict = field(default_factory=dict, repr=False)  # a window's points, by its sample rows and columns


def sample_depth(depth: np.ndarray, K: CameraLike, R_tilt: np.ndarray) -> SampledDepth:
    """``depth`` (H, W) metres (0 where missing) sampled and back-projected (SampledDepth)."""
    depth = np.asarray(depth, np.float64)
    R_tilt = np.asarray(R_tilt, np.float64)
    sampled = depth[::STRIDE, ::STRIDE]
    rows, cols = np.indices(sampled.shape, dtype=np.float64) * STRIDE  # the samples' pixels
    points = backproject(cols, rows, sampled, K) @ R_tilt.T
    return SampledDepth(depth, K, R_tilt, points, sampled > 0)


def depth_support(sampled: SampledDepth, boxes2d: np.ndarray, boxes3d: np.ndarray) -> np.ndarray:
    """(N,) share of the depth samples in each 2D box (N, 4) [x1, y1, x2, y2] whose points lie in
    its 3D box (N, 7), camera-frame centre, yaw in the tilt frame of ``sampled.R_tilt``; 0 where a
    2D box holds no depth."""
    out = np.zeros(len(boxes3d))
    held_points = box_points(sampled, boxes2d)
    for i, (held, box) in enumerate(zip(held_points, np.asarray(boxes3d), strict=True)):
        if len(held):
            out[i] = points_in_box(held, box, sampled.R_tilt, MARGIN_M, MARGIN_M).mean()
    return out


def box_points(sampled: SampledDepth, boxes2d: np.ndarray) -> list[np.ndarray]:
    """Per 2D box (N, 4), the tilt-frame points (P, 3) of its samples that have depth: what a box's
    support is counted over."""
    held = []
    for box2d in np.asarray(boxes2d):
        pixels = pixel_window(box2d, sampled.depth.shape)  # its samples: the pixels j * STRIDE among them
        key = tuple((-(-p.start // STRIDE), -(-p.stop // STRIDE)) for p in pixels)
        if key not in sampled.held:
            window = tuple(slice(*k) for k in key)
            points = sampled.points[window][sampled.valid[window]]
            points.setflags(write=False)  # shared by the steps that ask for it
            sampled.held[key] = points
        held.append(sampled.held[key])
    return held


def object_samples(
    sampled: SampledDepth, boxes2d: np.ndarray, floor: np.ndarray | None = None
) -> list[np.ndarray]:
    """Per 2D box (N, 4), at most ``OBJECT_POINTS`` of its samples' tilt-frame points, spread over
    it, without those within ``FLOOR_GAP_M`` of ``floor`` (step 8's plane, floor_contact.frame_floor;
    None: none left out): what steps 9 and 10 read an object's surface from."""
    out = []
    for points in box_points(sampled, boxes2d):
        points = evenly_spread(points, OBJECT_POINTS)
        if floor is not None:  # y is down: the floor's samples have the largest y
            points = points[points[:, 1] < points[:, [0, 2]] @ floor[:2] + floor[2] - FLOOR_GAP_M]
        out.append(points)
    return out


def rescored(
    scores: np.ndarray, sampled: SampledDepth, boxes2d: np.ndarray, boxes3d: np.ndarray
) -> np.ndarray:
    """The detections' ``scores`` moved by their support (``depth_support``'s arguments), those
    under ``MIN_SCORE`` as they are (a frame holds some 240 detections, 50 of them over it)."""
    scores = np.asarray(scores, np.float64)
    support = np.full(len(scores), SUPPORT_REFERENCE)
    some = scores >= MIN_SCORE
    support[some] = depth_support(sampled, np.asarray(boxes2d)[some], np.asarray(boxes3d)[some])
    return supported_scores(scores, support)


def supported_scores(scores: np.ndarray, support: np.ndarray) -> np.ndarray:
    """``scores`` moved in log-odds by the ``support`` (module docstring)."""
    p = np.clip(np.asarray(scores, np.float64), SCORE_EPS, 1 - SCORE_EPS)
    logit = np.log(p) - np.log1p(-p) + SUPPORT_WEIGHT * (np.asarray(support) - SUPPORT_REFERENCE)
    return 1.0 / (1.0 + np.exp(-logit))
