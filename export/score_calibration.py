"""The score calibration a3d-export fits into a model (``--score-calibration FOLDER``).

The exported model runs through the runtime's own pipeline (a3d.runtime.pipeline, the model's
settings, softmax scores) on every annotated frame of FOLDER; the evaluator
(a3d.runtime.evaluation.metric: the paper's protocol, 3D IoU 0.25) marks each detection right or
wrong; a3d.runtime.postprocess.score_calibration fits one increasing map per class. Take frames
the network did not train on that look like the frames it will see (another seed of its
training world): on its training frames a network is surer than anywhere else.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from a3d.export.base import ExportError
from a3d.runtime.evaluation.metric import EvalConfig, EvalResult, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import PipelineConfig, detect_frames
from a3d.runtime.postprocess.score_calibration import ScoreCalibration, fit_calibration
from a3d.runtime.sources.folder import FolderSource
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES

IOU = 0.25  # the paper's (and a3d-eval's primary) 3D IoU: what "right" means
REPORT_THRESHOLD = 0.5
PROGRESS_EVERY = 50  # frames between progress lines


def calibrate(model: DetectorModel, folder: Path, prog: str) -> tuple[ScoreCalibration, dict]:
    """The calibration fitted on ``folder`` and what it was fitted on (for the model's provenance),
    with the model's mAP@0.25 there (the calibration keeps every class's ranking, so its AP).

    Raises ExportError naming the folder when a frame fails or the detections hold no right or
    no wrong one.
    """
    result = score_on(model, folder, prog)
    scores = np.concatenate([c.scores for c in result.classes])
    classes = np.concatenate([np.full(c.num_det, CLASSES.index(c.name)) for c in result.classes])
    correct = np.concatenate([c.true_positives(IOU) for c in result.classes])
    try:
        calibration = fit_calibration(scores, classes, correct, NUM_CLASSES, IOU)
    except ValueError as e:
        raise ExportError(f"{folder}: cannot fit the score calibration: {e}") from None
    calibrated = calibration.apply(scores, classes)
    report = {
        "folder": str(folder.resolve()),
        "frames": result.num_frames,
        "detections": len(scores),
        "right": int(correct.sum()),
        "iou": IOU,
        f"right_share_at_{REPORT_THRESHOLD}": {
            "softmax": _right_share(scores, correct),
            "calibrated": _right_share(calibrated, correct),
        },
        "map25": result.map_all(IOU),
        "map25_present": result.map_present(IOU),
    }
    return calibration, report


def score_on(
    model: DetectorModel, folder: Path, prog: str, config: PipelineConfig | None = None
) -> EvalResult:
    """The model's detections on every annotated frame of ``folder``, scored at 3D IoU 0.25 by the
    evaluator (ExportError naming the folder for a frame that fails): run with ``config``, by default
    the model's settings with its softmax scores (the network alone, as calibrating needs it)."""
    truth, _ = load_truth(folder)
    if config is None:
        config = PipelineConfig.from_metadata(model.metadata, raw_scores=True)
    source = FolderSource(folder)
    if source.incomplete:
        raise ExportError(f"{folder}: incomplete frame {source.incomplete[0]}")
    detections = {}
    for done, outcome in enumerate(detect_frames(source, model, config), 1):
        if outcome.detections is None:
            raise ExportError(f"{folder}: a frame failed as it was scored: {outcome.problem}")
        if outcome.name in truth:
            detections[outcome.name] = outcome.detections
        if done % PROGRESS_EVERY == 0:
            print(f"{prog}: {folder.name}: {done}/{len(source)} frames", file=sys.stderr)
    return evaluate(truth, detections, EvalConfig(iou_thresholds=(IOU,)))


def _right_share(scores: np.ndarray, correct: np.ndarray) -> dict:
    """How many detections score >= REPORT_THRESHOLD and which share of them is right."""
    kept = scores >= REPORT_THRESHOLD
    share = float(correct[kept].mean()) if kept.any() else None
    return {"detections": int(kept.sum()), "right_share": share}
