"""Per-class score calibration: the network's softmax score -> the chance that a detection is right.

Why: a softmax trained on synthetic frames is over-confident on frames unlike them. On real rooms
about a quarter of the detections scoring >= 0.5 were right, and on frames with no object of any
class the network still fires at 0.5 on shelving, wall panels and clutter. A threshold should
mean the same thing for every class and every model, so a model can carry one logistic map per
class of the score's logit (Platt scaling):

    calibrated = sigmoid(slope[c] * logit(score) + intercept[c]),   slope[c] > 0

fitted (``fit_calibration``) to whether each detection of annotated frames the model did not
train on was right under the evaluation's matching (3D IoU >= ``iou``, greedy by score, a
duplicate is wrong; a3d.runtime.evaluation.metric). Each map is strictly increasing on scores in
[SCORE_EPS, 1 - SCORE_EPS], so within a class the order of the detections, and with it per-class
top-k, per-class NMS and every AP, is unchanged; only what a threshold means changes: 0.5 is "as
likely right as wrong" on frames like the calibration frames. Scores outside that range are
clipped to it first, so those below 1e-7 (or above 1 - 1e-7) tie with one another after the map;
the detections that can reorder are only ones the softmax itself put below 1e-7.

A class with few detections borrows strength from the fit over all classes: its two parameters
have a Gaussian prior centred on the pooled ones, ``PRIOR_WEIGHT`` strong: about what eight
detections at the 0.5 point weigh (each adds 1/4 to the log-likelihood's curvature), so a class
with dozens of right and wrong detections barely feels it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SHOW_THRESHOLD = 0.5
"""The score from which a3d shows a detection: a3d-run's viewer and summary (--view-min-score) and
``Detector.detect``'s default ``score_threshold``. With a model's calibrated scores a detection at
0.5 is as likely right as wrong; what share of the shown boxes is right is measured in docs/live.md."""
SCORE_EPS = 1e-7  # scores are clipped to [eps, 1 - eps] before the logit
MIN_SLOPE = 0.05  # a fitted slope below this is raised to it, keeping every map increasing
PRIOR_WEIGHT = 2.0  # each class's prior, centred on the pooled fit
POOLED_PRIOR_WEIGHT = 1.0  # the pooled fit's, centred on the identity map
NEWTON_STEPS = 100


@dataclass(frozen=True, eq=False)
class ScoreCalibration:
    """Per-class Platt maps: ``slope`` and ``intercept`` (C,) over CLASSES; ``iou`` the 3D IoU a
    detection needed to count as right when they were fitted."""

    slope: np.ndarray
    intercept: np.ndarray
    iou: float

    def __post_init__(self) -> None:
        slope, intercept = (np.asarray(a, np.float64) for a in (self.slope, self.intercept))
        if slope.ndim != 1 or slope.shape != intercept.shape:
            raise ValueError(f"slope {slope.shape} and intercept {intercept.shape} must be one (C,) shape")
        if not (np.all(np.isfinite(slope)) and np.all(np.isfinite(intercept)) and np.all(slope > 0)):
            raise ValueError("calibration slopes must be finite and positive, intercepts finite")
        object.__setattr__(self, "slope", slope)
        object.__setattr__(self, "intercept", intercept)

    def apply(self, scores: np.ndarray, class_idx: np.ndarray | None = None) -> np.ndarray:
        """Calibrated scores. ``scores`` (N, C) with one column per class (``class_idx`` None), or
        (K,) with each score's 0-based class in ``class_idx`` (K,)."""
        scores = np.asarray(scores, np.float64)
        if class_idx is None:
            if scores.ndim != 2 or scores.shape[1] != len(self.slope):
                raise ValueError(f"scores {scores.shape}: expected (N, {len(self.slope)}) without class_idx")
            slope, intercept = self.slope, self.intercept
        else:
            index = np.asarray(class_idx, np.int64)
            slope, intercept = self.slope[index], self.intercept[index]
        return _sigmoid(slope * logit(scores) + intercept)

    def to_dict(self) -> dict:
        return {"slope": self.slope.tolist(), "intercept": self.intercept.tolist(), "iou": float(self.iou)}


def logit(scores: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(scores, np.float64), SCORE_EPS, 1.0 - SCORE_EPS)
    return np.log(p) - np.log1p(-p)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))  # exact sigmoid, no overflow warning for large |x|


def fit_calibration(
    scores: np.ndarray, class_idx: np.ndarray, correct: np.ndarray, num_classes: int, iou: float
) -> ScoreCalibration:
    """Platt maps fitted to detections (K,) scores, 0-based classes and right/wrong flags.

    The pooled fit (all classes, a vague prior at the identity map) is the prior mean of each
    class's fit; a class without detections keeps the pooled map. Raises ValueError when the
    detections hold no right one or no wrong one: nothing then says where 0.5 lies.
    """
    x = logit(scores)
    class_idx = np.asarray(class_idx, np.int64)
    y = np.asarray(correct, bool).astype(np.float64)
    if not (x.shape == class_idx.shape == y.shape and x.ndim == 1):
        raise ValueError(f"scores {x.shape}, class_idx {class_idx.shape}, correct {y.shape}: one (K,) shape")
    if y.all() or not y.any():
        raise ValueError(
            f"{len(y)} calibration detections, {int(y.sum())} right: need both right and wrong ones"
        )
    pooled = _fit_logistic(x, y, np.array([1.0, 0.0]), POOLED_PRIOR_WEIGHT)
    params = np.tile(pooled, (num_classes, 1))
    for c in np.unique(class_idx):
        rows = class_idx == c
        params[c] = _fit_logistic(x[rows], y[rows], pooled, PRIOR_WEIGHT)
    return ScoreCalibration(np.maximum(params[:, 0], MIN_SLOPE), params[:, 1], iou)


def _fit_logistic(x: np.ndarray, y: np.ndarray, prior: np.ndarray, weight: float) -> np.ndarray:
    """MAP (slope, intercept) of P(y = 1) = sigmoid(slope x + intercept) under a Gaussian prior
    of precision ``weight`` at ``prior``: Newton's method with step halving (the objective is
    strictly convex, so this converges even where the flags are separable by score)."""
    design = np.stack([x, np.ones_like(x)], axis=1)

    def objective(t: np.ndarray) -> float:
        z = design @ t
        return float(np.sum(np.logaddexp(0.0, z) - y * z) + 0.5 * weight * np.sum((t - prior) ** 2))

    theta = prior.astype(np.float64)
    value = objective(theta)
    for _ in range(NEWTON_STEPS):
        p = _sigmoid(design @ theta)
        gradient = design.T @ (p - y) + weight * (theta - prior)
        hessian = (design * (p * (1.0 - p))[:, None]).T @ design + weight * np.eye(2)
        step = np.linalg.solve(hessian, gradient)
        while objective(theta - step) > value and np.max(np.abs(step)) > 1e-12:
            step = step / 2
        theta = theta - step
        value = objective(theta)
        if np.max(np.abs(step)) < 1e-10:
            break
    return theta
