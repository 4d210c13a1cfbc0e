"""One list of objects from a3d's own detections and a 2D detector's, each object once.

A 2D detector trained on real photographs (a3d.runtime.detector2d) knows a few of a3d's classes
far better on real frames than a network trained on synthetic rooms; a3d's own proposals and
classifier know all 19 and find objects the detector misses (half hidden, in the dark). The
detector's boxes therefore join the network's RoIs (the network infers their 3D box for the
detector's class) and both lists are kept:

- a detector box's class is its detector class's a3d class; where that maps to several (COCO's
  "tv": monitor or television) the network's score picks among them;
- its score fuses the two opinions in log-odds: the detector's counts fully, the network's by
  ``NETWORK_WEIGHT`` and read against ``NETWORK_REFERENCE``:
  ``sigmoid(logit(detector) + NETWORK_WEIGHT * (logit(network) - logit(NETWORK_REFERENCE)))``.
  The network was trained on synthetic rooms only: on real objects that a detector boxes its
  calibrated score is low (mostly 0.02 to 0.4 on real chairs, against below 0.03 on the detector's
  wrong boxes), so what carries evidence is its score against that level, not against 0.5, and
  it counts half as much as the detector's. Both constants were read off the real frames of
  docs/real-rooms.md, where what they give is measured;
- an own detection of the same class whose 2D box overlaps a detector box by IoU >=
  ``SAME_OBJECT_IOU`` (what detection benchmarks call the same object) is reported once, with the
  better score and both sources, on the RoI of the surer of the two: the detector's box where the
  detector's own score is at least the network's own detection's, else the network's RoI (its 2D
  box and the 3D box regressed from it). On real frames the detector is the surer and its box is
  the better RoI; on rooms like those it was trained on the network is, and its own segment the
  better RoI (docs/real-rooms.md measures both).

An image classifier trained on real photographs (a3d.runtime.classifier2d) gives a second opinion on
the frame's best own detections of the classes the detector does not know (``second_opinion``):
their score is fused with the classifier's probability of their class in log-odds, as the network's
with the detector's, by ``CLASSIFIER_WEIGHT`` against ``CLASSIFIER_REFERENCE``.

Each detection's source says where its class came from: the detector's name, "network", or both
("yolox-nano+network"); the classifier's name joins the source of those it scored
("network+mobilenet-v2").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.runtime.postprocess.score_calibration import SCORE_EPS
from a3d.runtime.structures.geometry import batched_nms_2d, iou_2d

NETWORK = "network"
NETWORK_WEIGHT = 0.5
NETWORK_REFERENCE = 0.05
SAME_OBJECT_IOU = 0.5
CLASSIFIER_WEIGHT = 0.5  # the network's weight and reference again; measured in docs/real-rooms.md
CLASSIFIER_REFERENCE = 0.05
SECOND_OPINIONS = 12  # own detections per frame the classifier looks at: the best, the ones that show


@dataclass(frozen=True)
class Picked:
    """Detections as rows of the network's outputs: ``rows`` (K,) RoI indices, ``class_idx`` (K,)
    0-based CLASSES, ``scores`` (K,) and ``sources`` (K,) where each class came from."""

    rows: np.ndarray
    class_idx: np.ndarray
    scores: np.ndarray
    sources: tuple[str, ...]


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), SCORE_EPS, 1 - SCORE_EPS)
    return np.log(p) - np.log1p(-p)


def _with_evidence(score: np.ndarray, other: np.ndarray, weight: float, reference: float) -> np.ndarray:
    """``score`` moved in log-odds by ``weight`` x the log-odds of ``other`` against ``reference``."""
    evidence = weight * (_logit(other) - _logit(np.float64(reference)))
    return 1.0 / (1.0 + np.exp(-(_logit(score) + evidence)))


def fused_score(detector: np.ndarray, network: np.ndarray) -> np.ndarray:
    """The detector's and the network's scores of one object as one (module docstring)."""
    return _with_evidence(detector, network, NETWORK_WEIGHT, NETWORK_REFERENCE)


def detector_picks(
    class_scores: np.ndarray, boxes2d: np.ndarray, first_row: int, detector_scores: np.ndarray,
    candidates: np.ndarray, name: str,
) -> Picked:  # fmt: skip
    """The detector's boxes as detections: RoIs ``first_row`` on, ``class_scores`` (N, C) and
    ``boxes2d`` (N, 4) of all RoIs (scores calibrated, no background), ``candidates`` (M, C) the
    classes each box may be. Two boxes of different detector classes can become the same a3d class
    (COCO's couch and chair both a chair); of those on one object (IoU over ``SAME_OBJECT_IOU``) the
    better-scored one is kept, so that the object is reported once."""
    m = len(detector_scores)
    rows = first_row + np.arange(m, dtype=np.int64)
    network = np.where(candidates, class_scores[rows], -1.0)
    class_idx = np.argmax(network, axis=1).astype(np.int64)
    scores = fused_score(detector_scores, network[np.arange(m), class_idx])
    keep = np.sort(batched_nms_2d(boxes2d[rows], scores, class_idx, SAME_OBJECT_IOU))
    return Picked(rows[keep], class_idx[keep], scores[keep], (name,) * len(keep))


def merge(own: Picked, found: Picked, boxes2d: np.ndarray, detector_scores: np.ndarray) -> Picked:
    """``own`` (network) and ``found`` (detector) detections as one list by descending score, an
    object both give counted once (module docstring); ``boxes2d`` (N, 4) the RoIs' boxes,
    ``detector_scores`` (M,) the detector's own scores of ``found``."""
    if not len(found.rows):
        return own
    same = iou_2d(boxes2d[own.rows], boxes2d[found.rows]) >= SAME_OBJECT_IOU
    same &= own.class_idx[:, None] == found.class_idx[None, :]
    rows = found.rows.copy()
    scores = found.scores.copy()
    sources = list(found.sources)
    for j in range(len(found.rows)):
        matched = np.flatnonzero(same[:, j])
        if len(matched):
            best = matched[np.argmax(own.scores[matched])]
            if own.scores[best] > detector_scores[j]:
                rows[j] = own.rows[best]
            scores[j] = max(scores[j], own.scores[best])
            sources[j] = f"{found.sources[j]}+{NETWORK}"
    alone = ~same.any(axis=1)
    all_rows = np.concatenate([own.rows[alone], rows])
    class_idx = np.concatenate([own.class_idx[alone], found.class_idx])
    all_scores = np.concatenate([own.scores[alone], scores])
    all_sources = [s for s, keep in zip(own.sources, alone, strict=True) if keep] + sources
    order = np.argsort(-all_scores, kind="stable")
    return Picked(all_rows[order], class_idx[order], all_scores[order], tuple(all_sources[i] for i in order))


def second_opinion_rows(picked: Picked, classes: np.ndarray, limit: int = SECOND_OPINIONS) -> np.ndarray:
    """Indices into ``picked`` of its ``limit`` best own detections (source "network") of the
    ``classes`` ((19,) bool) a classifier may score, best first."""
    own = np.array([source == NETWORK for source in picked.sources], bool)
    eligible = np.flatnonzero(own & np.asarray(classes, bool)[picked.class_idx])
    return eligible[np.argsort(-picked.scores[eligible], kind="stable")][:limit]


def second_opinion(picked: Picked, chosen: np.ndarray, class_probs: np.ndarray, name: str) -> Picked:
    """``picked`` with the ``chosen`` detections' scores fused with the classifier's probability of
    their class (``class_probs`` (K, 19), a row per chosen one) and ``name`` in their source, by
    descending score."""
    scores = picked.scores.astype(np.float64)
    probs = np.asarray(class_probs)[np.arange(len(chosen)), picked.class_idx[chosen]]
    scores[chosen] = _with_evidence(scores[chosen], probs, CLASSIFIER_WEIGHT, CLASSIFIER_REFERENCE)
    sources = list(picked.sources)
    for i in chosen:
        sources[i] = f"{sources[i]}+{name}"
    order = np.argsort(-scores, kind="stable")
    ordered = tuple(sources[i] for i in order)
    return Picked(picked.rows[order], picked.class_idx[order], scores[order], ordered)
