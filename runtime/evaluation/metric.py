"""The paper's 3D detection metric (docs/conventions.md "Evaluation"): greedy matching, 11-point AP,
mAP.

Protocol, exactly as scored here:

1. Optional 2D NMS per frame and class on the detections' ``box2d`` (IoU 0.3 by default), as the
   release does before scoring. It is idempotent on ``a3d-run`` output, which already had it.
2. 3D IoU in the tilt frame (``a3d.runtime.structures.geometry.iou_3d``) between each detection and the
   ground truth of its class in its frame. A detection whose line carries a different ``R_tilt``
   than the ground truth (an estimated gravity, say) is first re-expressed in the ground truth's
   tilt frame: its 8 camera-frame corners are rotated into that frame and a box is fitted to them
   with ``boxes_from_corners_tilt`` (the same conversion the authors' release applies to its
   8-corner annotations), so both sets share one frame and one yaw axis.
3. Greedy matching as the standard VOC code does it: per class, detections of the whole test set
   in descending score order (ties: frame order, then order within the frame); each takes the
   ground truth with the largest IoU in its frame; if that IoU >= the threshold and that ground
   truth is still unmatched, it is a true positive and marks it, otherwise a false positive
   (duplicates of a matched object, and detections of a class with no ground truth in the frame,
   are false positives). The paper writes "greater than 0.25"; docs/conventions.md and the release use >=.
4. AP per class: the 11-point interpolated average over recall t = 0, 0.1, ..., 1 of the largest
   precision at recall >= t (0 where the curve never reaches t). The points are ``k / 10``, not
   ``0.1 * k`` or ``arange(0, 1.1, 0.1)``: 0.1 * 3 = 0.30000000000000004 would wrongly skip a
   recall of exactly 3/10.
5. mAP, never NaN: ``map_all`` is the mean over all 19 classes, a class without ground truth in the
   set contributing 0 (the paper's "mean over the 19 classes"; on the NYUv2 test set every class
   is present); ``map_present`` is the mean over the classes that have ground truth (0 if none).
   A class with no ground truth has AP 0 and ``present == False`` whatever its detections; a class
   with ground truth but no detections has AP 0.

Pure numpy: the caller loads frames and detections (see ``a3d.runtime.cli.eval``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES
from a3d.runtime.structures.geometry import (
    batched_nms_2d,
    box_corners_camera,
    boxes_from_corners_tilt,
    iou_3d,
)

IOU_THRESHOLDS: tuple[float, ...] = (0.25, 0.5)  # primary first
NMS_IOU = 0.3
RECALL_POINTS = np.arange(11) / 10  # exactly k/10, see the module docstring
SAME_TILT_ATOL = 1e-9  # R_tilt entries closer than this are the same frame (JSON round trips are exact)


@dataclass(frozen=True)
class EvalConfig:
    """What to score: the IoU thresholds (the first is the primary one) and the optional 2D NMS."""

    iou_thresholds: tuple[float, ...] = IOU_THRESHOLDS
    nms_iou: float | None = NMS_IOU  # None: score the detections as given


@dataclass(frozen=True)
class FrameTruth:
    """One annotated frame's ground truth: classes (0-based CLASSES index) and amodal 3D boxes.

    ``boxes3d`` are ``[x, y, z, l, w, h, theta]`` in the camera frame, theta in the tilt frame of
    ``R_tilt`` (``p_tilt = R_tilt p_cam``).
    """

    class_ids: np.ndarray  # (N,) int
    boxes3d: np.ndarray  # (N, 7)
    R_tilt: np.ndarray  # (3, 3)


@dataclass(frozen=True)
class ClassResult:
    """Scores of one class. Curves are per threshold, over its detections in ranked order."""

    name: str
    num_gt: int
    num_det: int  # detections scored (after NMS), in annotated frames
    ap: dict[float, float]
    recall: dict[float, np.ndarray]  # (num_det,) cumulative recall; zeros when num_gt == 0
    precision: dict[float, np.ndarray]  # (num_det,) cumulative precision
    scores: np.ndarray  # (num_det,) descending

    @property
    def present(self) -> bool:
        """Whether the class has ground truth in the set, i.e. whether its AP means anything."""
        return self.num_gt > 0

    def curve_corners(self, threshold: float) -> np.ndarray:
        """(K, 3) rows (recall, precision, score) at each true positive and at the last detection.

        Precision peaks exactly at true positives, so these points carry the interpolated curve
        and the AP while staying at most num_gt + 1 long (eval.json stores these, not 10^5 rows).
        """
        if self.num_det == 0:
            return np.zeros((0, 3))
        recall, precision = self.recall[threshold], self.precision[threshold]
        steps = np.flatnonzero(np.diff(recall, prepend=0.0) > 0)
        keep = np.union1d(steps, [self.num_det - 1])
        return np.stack([recall[keep], precision[keep], self.scores[keep]], axis=1)


@dataclass(frozen=True)
class EvalResult:
    """Per-class results (CLASSES order), both mAPs per threshold and the bookkeeping of frames."""

    config: EvalConfig
    classes: list[ClassResult]
    num_frames: int  # annotated frames scored
    frames_without_detections: list[str] = field(default_factory=list)
    retilted_frames: list[str] = field(default_factory=list)  # detections re-expressed in the GT tilt

    def map_all(self, threshold: float) -> float:
        """Mean AP over all 19 classes; classes without ground truth count as 0 (the paper's mAP)."""
        return float(sum(c.ap[threshold] for c in self.classes) / NUM_CLASSES)

    def map_present(self, threshold: float) -> float:
        """Mean AP over the classes with ground truth in the set; 0.0 if there are none."""
        present = [c.ap[threshold] for c in self.classes if c.present]
        return float(np.mean(present)) if present else 0.0

    @property
    def absent_classes(self) -> list[str]:
        return [c.name for c in self.classes if not c.present]


def interpolated_ap_11(recall: np.ndarray, precision: np.ndarray) -> float:
    """11-point interpolated AP: mean over t = 0, 0.1, ..., 1 of max precision at recall >= t (0 if none).

    ``recall`` must be non-decreasing (a ranked list's cumulative recall).
    """
    if len(recall) == 0:
        return 0.0
    envelope = np.maximum.accumulate(precision[::-1])[::-1]  # max precision at this rank or later
    first = np.searchsorted(recall, RECALL_POINTS, side="left")  # first rank with recall >= t
    reached = first < len(recall)
    return float(np.where(reached, envelope[np.minimum(first, len(recall) - 1)], 0.0).mean())


def greedy_true_positives(best_gt: np.ndarray, best_iou: np.ndarray, threshold: float) -> np.ndarray:
    """VOC greedy assignment, vectorised. Inputs in descending score order; returns tp (D,) bool.

    ``best_gt`` is the set-wide index of each detection's max-IoU ground truth (-1: none in its
    frame). A ground truth is marked only by a true positive, so the true positives are exactly
    the first detection, in rank order, of each ground truth among those with IoU >= threshold.
    """
    tp = np.zeros(len(best_gt), dtype=bool)
    candidates = np.flatnonzero((best_iou >= threshold) & (best_gt >= 0))
    _, first = np.unique(best_gt[candidates], return_index=True)
    tp[candidates[first]] = True
    return tp


def retilt_boxes(boxes3d: np.ndarray, R_from: np.ndarray, R_to: np.ndarray) -> np.ndarray:
    """Re-express boxes whose theta is in the tilt frame of ``R_from`` in that of ``R_to``.

    Camera-frame corners are invariant; they are rotated into the new tilt frame and a box is
    fitted to them there (exact when the two frames share the vertical; otherwise the fit of
    ``boxes_from_corners_tilt``).
    """
    if len(boxes3d) == 0:
        return boxes3d
    corners_tilt = box_corners_camera(boxes3d, R_from) @ np.asarray(R_to, dtype=np.float64).T
    return boxes_from_corners_tilt(corners_tilt, R_to)


def _nms_keep(det: FrameDetections, nms_iou: float | None) -> np.ndarray:
    if nms_iou is None or len(det.scores) == 0:
        return np.arange(len(det.scores))
    return np.asarray(batched_nms_2d(det.boxes2d, det.scores, det.class_ids, nms_iou), dtype=np.int64)


@dataclass
class _Matches:
    """Set-wide detection table, filled frame by frame (lists of per-frame arrays)."""

    class_ids: list[np.ndarray] = field(default_factory=list)
    scores: list[np.ndarray] = field(default_factory=list)
    best_gt: list[np.ndarray] = field(default_factory=list)
    best_iou: list[np.ndarray] = field(default_factory=list)

    def add_frame(
        self,
        truth: FrameTruth,
        gt_offset: int,
        class_ids: np.ndarray,
        scores: np.ndarray,
        boxes3d: np.ndarray,
    ) -> None:
        """Best ground truth (of the same class, same frame) of each detection of one frame.

        One IoU matrix per class present in both (not one frame-wide matrix masked by class:
        iou_3d would clip the polygons of every overlapping other-class pair, 2-3x slower).
        """
        best_gt = np.full(len(scores), -1, dtype=np.int64)
        best_iou = np.zeros(len(scores))
        for c in np.intersect1d(class_ids, truth.class_ids):
            rows = np.flatnonzero(class_ids == c)
            gt_index = np.flatnonzero(truth.class_ids == c)
            iou = iou_3d(boxes3d[rows], truth.boxes3d[gt_index], truth.R_tilt)
            best = np.argmax(iou, axis=1)  # first of equal maxima, as VOC's argmax
            best_iou[rows] = iou[np.arange(len(rows)), best]
            best_gt[rows] = gt_offset + gt_index[best]
        self.class_ids.append(class_ids)
        self.scores.append(scores)
        self.best_gt.append(best_gt)
        self.best_iou.append(best_iou)


def _class_result(
    name: str,
    num_gt: int,
    scores: np.ndarray,
    best_gt: np.ndarray,
    best_iou: np.ndarray,
    thresholds: tuple[float, ...],
) -> ClassResult:
    order = np.argsort(-scores, kind="stable")  # ties: frame name order, then order in the frame
    best_gt, best_iou = best_gt[order], best_iou[order]
    ranks = np.arange(1, len(order) + 1)
    ap, recall, precision = {}, {}, {}
    for thr in thresholds:
        tp_cum = np.cumsum(greedy_true_positives(best_gt, best_iou, thr))
        precision[thr] = tp_cum / ranks
        recall[thr] = tp_cum / num_gt if num_gt > 0 else np.zeros(len(order))
        ap[thr] = interpolated_ap_11(recall[thr], precision[thr]) if num_gt > 0 else 0.0
    return ClassResult(name, num_gt, len(order), ap, recall, precision, scores[order])


def evaluate(
    truth: Mapping[str, FrameTruth],
    detections: Mapping[str, FrameDetections],
    config: EvalConfig | None = None,
) -> EvalResult:
    """Score detections against ground truth, keyed by frame name.

    Every frame in ``truth`` is part of the test set; a frame without detections has all its
    objects missed. Detections of frames not in ``truth`` are a ValueError: the caller decides
    what an unannotated frame means (``a3d-eval`` skips them with a warning).
    """
    config = config or EvalConfig()
    unknown = sorted(set(detections) - set(truth))
    if unknown:
        raise ValueError(f"detections for frames without ground truth: {', '.join(unknown[:5])}")
    matches = _Matches()
    gt_class_ids, missing, retilted = [], [], []
    gt_offset = 0
    for name in sorted(truth):
        frame_truth = truth[name]
        gt_class_ids.append(np.asarray(frame_truth.class_ids, dtype=np.int64))
        det = detections.get(name)
        if det is None:
            missing.append(name)
        else:
            keep = _nms_keep(det, config.nms_iou)
            boxes = det.boxes3d[keep]
            if not np.allclose(det.R_tilt, frame_truth.R_tilt, rtol=0.0, atol=SAME_TILT_ATOL):
                boxes = retilt_boxes(boxes, det.R_tilt, frame_truth.R_tilt)
                retilted.append(name)
            matches.add_frame(frame_truth, gt_offset, det.class_ids[keep], det.scores[keep], boxes)
        gt_offset += len(frame_truth.class_ids)

    all_gt = np.concatenate(gt_class_ids) if gt_class_ids else np.zeros(0, dtype=np.int64)
    num_gt = np.bincount(all_gt, minlength=NUM_CLASSES)
    class_ids, scores, best_gt, best_iou = (
        np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
        for parts, dtype in (
            (matches.class_ids, np.int64),
            (matches.scores, np.float64),
            (matches.best_gt, np.int64),
            (matches.best_iou, np.float64),
        )
    )
    by_class = np.argsort(class_ids, kind="stable")  # group by class, keeping set order inside
    bounds = np.searchsorted(class_ids[by_class], np.arange(NUM_CLASSES + 1))
    results = []
    for c, name in enumerate(CLASSES):
        rows = by_class[bounds[c] : bounds[c + 1]]
        results.append(
            _class_result(
                name, int(num_gt[c]), scores[rows], best_gt[rows], best_iou[rows], config.iou_thresholds
            )
        )
    return EvalResult(config, results, len(truth), missing, retilted)
