"""The ground truth of a frame folder in the evaluator's form, for a3d-eval and training's validation."""

from __future__ import annotations

from pathlib import Path

from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.metric import FrameTruth
from a3d.runtime.sources.folder import list_frames, read_ground_truth, read_meta


def load_truth(folder: Path) -> tuple[dict[str, FrameTruth], list[str]]:
    """Ground truth of the annotated frames, and the names of the frames without ground truth."""
    truth: dict[str, FrameTruth] = {}
    unannotated: list[str] = []
    for ref in list_frames(folder):
        gt = read_ground_truth(ref)
        if gt is None:
            unannotated.append(ref.name)
            continue
        # read_ground_truth has checked that a frame with ground truth gives R_tilt.
        truth[ref.name] = FrameTruth(gt.class_ids, gt.boxes3d, read_meta(ref).R_tilt)
    if not truth:
        raise InputError(f"{folder}: no frame has ground truth (NAME.gt.json)")
    return truth, unannotated
