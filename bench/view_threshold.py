"""What the viewer should show: precision of the bundled model's detections above a score.

a3d-run writes every detection down to ``--score-threshold`` (the evaluator needs the low ones
to trace the precision-recall curve) but the viewer draws only those scoring at least
``--view-min-score``. This picks that default from measured precision on held-out a3d-synth
frames (rendered in memory at the training size, run as a3d-run runs them: the bundled model,
the model's proposals and settings, the frame's own R_tilt).

A shown box is right when it is the best-scoring unmatched box of its class over a ground-truth
object with 3D IoU >= 0.25 (greedy by score, per frame and class, as the metric matches): a
duplicate of a found object counts as wrong, as it is one more box on the screen. Per score
threshold the table gives the boxes shown per frame, the precision (right / shown) and the
share of the objects found.

    .venv/bin/python -m bench.view_threshold [--first 920000] [--count 20]
"""

from __future__ import annotations

import argparse

import numpy as np

from a3d.runtime.models import model_path
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import PipelineConfig, detect
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import iou_3d

THRESHOLDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
MATCH_IOU = 0.25


def right_boxes(det, gt) -> np.ndarray:
    """(N,) bool: detection i is matched to a ground-truth object of its class (greedy by score)."""
    right = np.zeros(len(det.scores), bool)
    for c in np.unique(det.class_ids):
        mine = np.flatnonzero(det.class_ids == c)
        mine = mine[np.argsort(-det.scores[mine], kind="stable")]
        truth = np.flatnonzero(gt.class_ids == c)
        if not len(truth):
            continue
        overlaps = iou_3d(det.boxes3d[mine], gt.boxes3d[truth], det.R_tilt)
        taken = np.zeros(len(truth), bool)
        for row, i in enumerate(mine):
            candidates = np.where(taken, -1.0, overlaps[row])
            best = int(np.argmax(candidates))
            if candidates[best] >= MATCH_IOU:
                taken[best] = right[i] = True
    return right


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, default=920_000, help="first seed (held out of training)")
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument("--model", default=str(model_path("live")))
    args = parser.parse_args()
    from a3d.synth.scene import generate_frame

    model = DetectorModel.load(args.model, threads=2)
    config = PipelineConfig.from_metadata(model.metadata, proposal_source="compute")
    scores, right, n_objects = [], [], 0
    for seed in range(args.first, args.first + args.count):
        f = generate_frame(seed)
        frame = Frame(f"s{seed}", f.color[..., ::-1].copy(), f.depth, f.intrinsics, f.R_tilt)
        det = detect(frame, model, config)
        scores.append(det.scores)
        right.append(right_boxes(det, f.gt))
        n_objects += len(f.gt)
    s, r = np.concatenate(scores), np.concatenate(right)
    print(f"{args.count} a3d-synth frames (seeds {args.first}+), {n_objects} objects, model {args.model}")
    print("score >=  shown/frame  precision  objects found")
    for t in THRESHOLDS:
        shown = s >= t
        precision = r[shown].mean() if shown.any() else float("nan")
        print(
            f"{t:8.1f} {shown.sum() / args.count:12.1f} {precision:10.2f} {r[shown].sum() / n_objects:14.2f}"
        )


if __name__ == "__main__":
    main()
