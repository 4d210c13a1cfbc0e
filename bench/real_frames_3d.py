"""The 3D score of bench.real_frames: AP@0.25 against the real frames' 3D boxes, and how close the
3D boxes of the objects it finds are.

bench/data/real_frames_boxes3d.json gives most hand-drawn objects an amodal 3D box (fitted once,
corrected by hand: bench.real_frames_fit). Against it:

* **AP@0.25 per class and mAP**, a3d's own metric (``a3d.runtime.evaluation``, the paper's protocol,
  as ``a3d-eval`` scores): all the model's detections, 3D IoU >= 0.25, over the classes that have
  a 3D box in the file (mAP is the mean over those). A detection of an object the file skips
  counts as a false positive, as in any test set.
* **3D IoU of the objects found**: for each object with a 3D box that the 2D count found, the
  largest 3D IoU of a detection of its class at or above the threshold; their median. It says
  how good the 3D boxes are of what a user sees the model find.

Detections carry the R_tilt a3d estimates per frame, the file stores the one it was drawn in: the
same numbers when both come from the same depth, and otherwise the detections are re-expressed in
the file's tilt frame through their camera-frame corners (``metric.retilt_boxes``, as ``evaluate``
does).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from a3d.runtime.evaluation.metric import (
    SAME_TILT_ATOL,
    ClassResult,
    EvalConfig,
    EvalResult,
    FrameTruth,
    evaluate,
    retilt_boxes,
)
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import iou_3d

IOU_3D = 0.25  # the paper's threshold


@dataclass(frozen=True)
class Score3D:
    """The 3D numbers: ``result`` a3d's metric at ``IOU_3D`` against ``truth``; per frame, per
    object of ``truth``, whether the 2D count found it and its best same-class 3D IoU."""

    truth: dict[str, FrameTruth]
    result: EvalResult
    found: dict[str, np.ndarray]  # (N,) bool
    best_iou: dict[str, np.ndarray]  # (N,) float

    @property
    def classes(self) -> list[ClassResult]:
        """The classes with a 3D box in the file, CLASSES order."""
        return [c for c in self.result.classes if c.present]

    @property
    def map(self) -> float:
        """Mean AP@0.25 over ``classes``."""
        return self.result.map_present(IOU_3D)

    @property
    def found_ious(self) -> np.ndarray:
        """Best 3D IoUs of the objects found, frame by frame."""
        return np.concatenate([self.best_iou[f][self.found[f]] for f in self.best_iou] or [np.zeros(0)])

    @property
    def median_iou(self) -> float | None:
        ious = self.found_ious
        return float(np.median(ious)) if len(ious) else None


def best_ious(truth: FrameTruth, det: FrameDetections, threshold: float) -> np.ndarray:
    """(N,) per object of ``truth`` the largest 3D IoU of a detection of its class scoring at least
    ``threshold`` (0 without one), in the truth's tilt frame."""
    keep = det.scores >= threshold
    boxes = det.boxes3d[keep]
    if not np.allclose(det.R_tilt, truth.R_tilt, rtol=0.0, atol=SAME_TILT_ATOL):
        boxes = retilt_boxes(boxes, det.R_tilt, truth.R_tilt)
    ious = iou_3d(boxes, truth.boxes3d, truth.R_tilt)
    same = det.class_ids[keep][:, None] == np.asarray(truth.class_ids)[None, :]
    return np.where(same, ious, 0.0).max(axis=0, initial=0.0)


def score_3d(
    truth: Mapping[str, FrameTruth],
    detections: Mapping[str, FrameDetections],
    found: Mapping[str, np.ndarray],
    threshold: float,
) -> Score3D:
    """The 3D score (module docstring) of every frame's detections (all scores) against ``truth``;
    ``found`` says per frame which of its 3D-boxed objects the 2D count found at ``threshold``."""
    result = evaluate(truth, detections, EvalConfig(iou_thresholds=(IOU_3D,)))
    best = {name: best_ious(truth[name], detections[name], threshold) for name in truth}
    return Score3D(dict(truth), result, {name: np.asarray(found[name], bool) for name in truth}, best)


def markdown_3d(score: Score3D) -> str:
    """AP@0.25 per class with a 3D box and their mean, in markdown, and the median IoU line."""
    lines = ["| class | objects | detections | AP@0.25 |", "|---|---:|---:|---:|"]
    for c in score.classes:
        lines.append(f"| {c.name} | {c.num_gt} | {c.num_det} | {100 * c.ap[IOU_3D]:.1f} |")
    objects = sum(c.num_gt for c in score.classes)
    lines.append(f"| **mAP** | {objects} | | {100 * score.map:.1f} |")
    ious = score.found_ious
    median = "-" if score.median_iou is None else f"{score.median_iou:.2f}"
    lines.append(
        f"\n3D IoU of the {len(ious)} found objects that have a 3D box (the best detection of their class "
        f"at the threshold): median {median}"
    )
    return "\n".join(lines)


def as_dict(score: Score3D, objects: Mapping[str, np.ndarray]) -> dict:
    """The 3D numbers for real_frames.json; ``objects`` names each frame's 3D-boxed objects by
    their index in the boxes file."""
    return {
        "iou": IOU_3D,
        "protocol": score.result.config.protocol.name,
        "classes": {
            c.name: {"objects": c.num_gt, "detections": c.num_det, "ap": c.ap[IOU_3D]} for c in score.classes
        },
        "map": score.map,
        "found": len(score.found_ious),
        "median_iou": score.median_iou,
        "retilted_frames": score.result.retilted_frames,
        "frames": {
            name: [
                {"object": int(i), "class": CLASSES[c], "found": bool(f), "iou": round(float(iou), 4)}
                for i, c, f, iou in zip(
                    objects[name], truth.class_ids, score.found[name], score.best_iou[name], strict=True
                )
            ]
            for name, truth in score.truth.items()
        },
    }
