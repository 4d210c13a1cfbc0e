"""The 3D detection metric: greedy matching, AP per class, mAP, under a named protocol.

The protocol (``a3d.runtime.evaluation.protocols``: ``paper`` by default, ``authors``, ``sunrgbd``)
fixes every rule that changes a number; the steps, as scored here:

1. Optional 2D NMS per frame and class on the detections' ``box2d`` (IoU 0.3 in ``paper`` and
   ``authors``, continuous or +1-pixel widths; none in ``sunrgbd``), as the release does before
   scoring. It is idempotent on ``a3d-run`` output, which already had the continuous one.
2. Classes outside the protocol's list are dropped, ground truth and detections alike (counted).
3. 3D IoU in the tilt frame (``a3d.runtime.structures.geometry.iou_3d``) between each detection
   and the ground truth of its class in its frame. A detection whose line carries a different
   ``R_tilt`` than the ground truth (an estimated gravity, say) is first re-expressed in the
   ground truth's tilt frame: its 8 camera-frame corners are rotated into that frame and a box is
   fitted to them with ``boxes_from_corners_tilt`` (the same conversion the authors' release
   applies to its 8-corner annotations), so both sets share one frame and one yaw axis.
4. Greedy matching as the standard VOC code does it: per class, detections of the whole test set
   in descending score order (ties: the protocol's frame order, then order within the frame);
   each takes the ground truth with the largest IoU in its frame (the first of equal maxima); if
   that IoU passes the threshold (>= in ``paper``/``authors``, > in ``sunrgbd``) and that ground
   truth is still unmatched, it is a true positive and marks it, otherwise a false positive
   (duplicates of a matched object, and detections of a class with no ground truth in the frame,
   are false positives).
5. AP per class from the cumulative precision and recall of the ranked list: 11-point (the max
   precision at recall >= t, 0 where the curve never reaches t, over the protocol's 11 points)
   or the area under the interpolated curve (``sunrgbd``).
6. mAP, never NaN: ``map_all`` is the mean over the protocol's classes, a class without ground
   truth in the set contributing 0 (the paper's "mean over the 19 classes"; on the NYUv2 test set
   every class is present); ``map_present`` is the mean over the classes that have ground truth
   (0 if none). A class with no ground truth has AP 0 and ``present == False`` whatever its
   detections; a class with ground truth but no detections has AP 0.

Pure numpy: the caller loads frames and detections (see ``a3d.runtime.cli.eval``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from a3d.runtime.evaluation.protocols import EXACT_TENTHS, PAPER, APRule, Protocol
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
SAME_TILT_ATOL = 1e-9  # R_tilt entries closer than this are the same frame (JSON round trips are exact)
PROTOCOL_NMS = -1.0
"""``EvalConfig.nms_iou`` default: the protocol's own 2D NMS (0.3 for paper and authors, none for sunrgbd)."""


@dataclass(frozen=True)
class EvalConfig:
    """What to score: IoU thresholds (the first is the primary one), 2D NMS, and the protocol.

    ``nms_iou`` left at ``PROTOCOL_NMS`` takes the protocol's; a number or None overrides it (the
    NMS box convention stays the protocol's).
    """

    iou_thresholds: tuple[float, ...] = IOU_THRESHOLDS
    nms_iou: float | None = PROTOCOL_NMS  # None: score the detections as given
    protocol: Protocol = PAPER

    def __post_init__(self) -> None:
        if self.nms_iou == PROTOCOL_NMS:
            object.__setattr__(self, "nms_iou", self.protocol.nms_iou)

    @property
    def protocol_nms(self) -> bool:
        """Whether the 2D NMS is the protocol's own (not overridden)."""
        return self.nms_iou == self.protocol.nms_iou


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

    def true_positives(self, threshold: float) -> np.ndarray:
        """(num_det,) bool in ranked order: which detections the matching at ``threshold`` counted right."""
        ranks = np.arange(1, self.num_det + 1)
        return np.diff(np.rint(self.precision[threshold] * ranks), prepend=0.0) > 0.5

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
    """Per-class results (the protocol's classes, CLASSES order), both mAPs per threshold and the
    bookkeeping of frames and of what the protocol's class list left out."""

    config: EvalConfig
    classes: list[ClassResult]
    num_frames: int  # annotated frames scored
    frames_without_detections: list[str] = field(default_factory=list)
    retilted_frames: list[str] = field(default_factory=list)  # detections re-expressed in the GT tilt
    ignored_gt: int = 0  # ground-truth objects of classes outside the protocol's list
    ignored_det: int = 0  # detections (after NMS) of classes outside the protocol's list

    def map_all(self, threshold: float) -> float:
        """Mean AP over the protocol's classes; classes without ground truth count as 0 (the paper's mAP).

        Summed in class order, as MATLAB's ``mean(APs)``; mmdetection3d's ``np.mean`` of its float32
        APs for ``sunrgbd``.
        """
        aps = [c.ap[threshold] for c in self.classes]
        if self.config.protocol.ap_float32:
            return float(np.mean(np.asarray(aps, dtype=np.float32)))
        return float(sum(aps) / len(aps))

    def map_present(self, threshold: float) -> float:
        """Mean AP over the classes with ground truth in the set; 0.0 if there are none."""
        present = [c.ap[threshold] for c in self.classes if c.present]
        dtype = np.float32 if self.config.protocol.ap_float32 else np.float64
        return float(np.mean(np.asarray(present, dtype=dtype))) if present else 0.0

    @property
    def absent_classes(self) -> list[str]:
        return [c.name for c in self.classes if not c.present]


def eleven_point_values(
    recall: np.ndarray, precision: np.ndarray, points: tuple[float, ...] = EXACT_TENTHS
) -> np.ndarray:
    """Max precision at recall >= t for each recall point t (0 where the curve never reaches t).

    ``recall`` must be non-decreasing (a ranked list's cumulative recall).
    """
    if len(recall) == 0:
        return np.zeros(len(points))
    envelope = np.maximum.accumulate(precision[::-1])[::-1]  # max precision at this rank or later
    first = np.searchsorted(recall, np.asarray(points), side="left")  # first rank with recall >= t
    reached = first < len(recall)
    return np.where(reached, envelope[np.minimum(first, len(recall) - 1)], 0.0)


def interpolated_ap_11(
    recall: np.ndarray,
    precision: np.ndarray,
    points: tuple[float, ...] = EXACT_TENTHS,
    running_sum: bool = False,
) -> float:
    """11-point interpolated AP: the mean over the recall points of ``eleven_point_values``.

    ``running_sum``: ``ap = ap + p / 11`` point by point, as the release's MATLAB does (the last
    bits differ from the mean: eleven 1s give 1.0000000000000002).
    """
    values = eleven_point_values(recall, precision, points)
    if not running_sum:
        return float(values.mean())
    ap = 0.0
    for p in values.tolist():
        ap = ap + p / len(points)
    return ap


def area_ap(recall: np.ndarray, precision: np.ndarray) -> float:
    """Area under the interpolated PR curve, VOC 2010+ style, step for step as mmdetection3d's
    ``average_precision(mode='area')``: the curve padded with (0, 0) and (1, 0), its precision
    made non-increasing from the right, summed over the recall steps (in float64; the float32
    rounding is the caller's)."""
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.maximum.accumulate(np.concatenate([[0.0], precision, [0.0]])[::-1])[::-1]
    steps = np.flatnonzero(mrec[1:] != mrec[:-1])
    return float(np.sum((mrec[steps + 1] - mrec[steps]) * mpre[steps + 1]))


def average_precision(protocol: Protocol, recall: np.ndarray, precision: np.ndarray) -> float:
    """The protocol's AP of one class's ranked curve."""
    if protocol.ap_rule is APRule.AREA:
        ap = area_ap(recall, precision)
    else:
        ap = interpolated_ap_11(recall, precision, protocol.recall_points, protocol.running_sum)
    return float(np.float32(ap)) if protocol.ap_float32 else ap


def greedy_true_positives(
    best_gt: np.ndarray, best_iou: np.ndarray, threshold: float, strict: bool = False
) -> np.ndarray:
    """VOC greedy assignment, vectorised. Inputs in descending score order; returns tp (D,) bool.

    ``best_gt`` is the set-wide index of each detection's max-IoU ground truth (-1: none in its
    frame). A ground truth is marked only by a true positive, so the true positives are exactly
    the first detection, in rank order, of each ground truth among those with IoU >= threshold
    (> threshold when ``strict``).
    """
    tp = np.zeros(len(best_gt), dtype=bool)
    passes = best_iou > threshold if strict else best_iou >= threshold
    candidates = np.flatnonzero(passes & (best_gt >= 0))
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


def _nms_keep(det: FrameDetections, config: EvalConfig) -> np.ndarray:
    if config.nms_iou is None or len(det.scores) == 0:
        return np.arange(len(det.scores))
    plus_one = config.protocol.nms_plus_one
    keep = batched_nms_2d(det.boxes2d, det.scores, det.class_ids, config.nms_iou, plus_one)
    return np.asarray(keep, dtype=np.int64)


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
    config: EvalConfig,
) -> ClassResult:
    protocol = config.protocol
    order = np.argsort(-scores, kind="stable")  # ties: the protocol's frame order, then order in the frame
    best_gt, best_iou = best_gt[order], best_iou[order]
    ranks = np.arange(1, len(order) + 1)  # = tp + fp; mmdetection3d's max(tp + fp, eps) is the same
    ap, recall, precision = {}, {}, {}
    for thr in config.iou_thresholds:
        tp_cum = np.cumsum(greedy_true_positives(best_gt, best_iou, thr, protocol.strict_iou))
        precision[thr] = tp_cum / ranks
        recall[thr] = tp_cum / num_gt if num_gt > 0 else np.zeros(len(order))
        ap[thr] = average_precision(protocol, recall[thr], precision[thr]) if num_gt > 0 else 0.0
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
    protocol = config.protocol
    scored = np.asarray(protocol.class_ids, dtype=np.int64)
    unknown = sorted(set(detections) - set(truth))
    if unknown:
        raise ValueError(f"detections for frames without ground truth: {', '.join(unknown[:5])}")
    matches = _Matches()
    gt_class_ids, missing, retilted = [], [], []
    gt_offset, ignored_det = 0, 0
    for name in sorted(truth, key=protocol.frame_key):
        frame_truth = truth[name]
        gt_class_ids.append(np.asarray(frame_truth.class_ids, dtype=np.int64))
        det = detections.get(name)
        if det is None:
            missing.append(name)
        else:
            keep = _nms_keep(det, config)
            in_protocol = np.isin(det.class_ids[keep], scored)
            ignored_det += int(np.count_nonzero(~in_protocol))
            keep = keep[in_protocol]
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
    for c in protocol.class_ids:
        rows = by_class[bounds[c] : bounds[c + 1]]
        results.append(
            _class_result(CLASSES[c], int(num_gt[c]), scores[rows], best_gt[rows], best_iou[rows], config)
        )
    ignored_gt = len(all_gt) - int(num_gt[scored].sum())
    return EvalResult(config, results, len(truth), missing, retilted, ignored_gt, ignored_det)
