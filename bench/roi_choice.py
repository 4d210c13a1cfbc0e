"""Where a model's 3D boxes are lost: no RoI on the object, no RoI whose 3D box reaches it, or the
wrong RoI scored highest.

    .venv/bin/python -m bench.roi_choice FRAMES [--model real|FILE]

For every ground-truth object of FRAMES (a frame folder with ground truth), per class:

- *covered*: some RoI of the pipeline (a3d's segment proposals and, with a 2D detector, its boxes)
  overlaps the object's visible 2D box at IoU >= 0.5;
- *best reaches*: of those RoIs, the best 3D box the network regresses for the object's class
  reaches it at 3D IoU >= 0.25 (what a perfect choice among them would find);
- *top reaches*: the 3D box of the one the network scores highest for that class does (what the
  pipeline's selection keeps, before the depth steps of docs/real-rooms.md move it).

The gap between the last two is what a model's scores cannot tell apart: RoIs with one box and
different lifted centres (a chair's segment with the wall behind it) have one score.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from a3d.runtime.detector import Detector
from a3d.runtime.evaluation.metric import retilt_boxes
from a3d.runtime.pipeline import infer, load_and_prepare
from a3d.runtime.postprocess.select import decode_detections
from a3d.runtime.sources.registry import open_source
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import iou_2d, iou_3d

FIELDS = ("objects", "covered", "best", "top")


def roi_choice(frames: Path, model: str) -> dict[str, dict[str, int]]:
    """Per class, the counts of the module docstring."""
    detector = Detector.load(model)
    config = detector.config
    counts: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(FIELDS, 0))
    for loader in open_source(frames, with_truth=True):
        prepared = load_and_prepare(loader, config)
        truth = prepared.frame.truth
        if truth is None or not len(truth.class_ids):
            continue
        out = infer(detector.model, prepared)
        scores = out.probs[:, 1:]
        if config.score_calibration is not None:
            scores = config.score_calibration.apply(scores)
        overlaps = iou_2d(np.asarray(truth.boxes2d_visible, np.float64), prepared.native_boxes)
        for i, (cls, box) in enumerate(zip(truth.class_ids, truth.boxes3d, strict=True)):
            tally = counts[CLASSES[cls]]
            tally["objects"] += 1
            rows = np.flatnonzero(overlaps[i] >= 0.5)
            if not len(rows):
                continue
            tally["covered"] += 1
            boxes3d, _ = decode_detections(
                rows, np.full(len(rows), cls), prepared.centers, config.mean_sizes, prepared.boxes,
                out.deltas3d, out.deltas2d, prepared.work.image_size,
            )  # fmt: skip
            tilt = np.asarray(prepared.frame.R_tilt, np.float64)  # the ground truth's gravity
            boxes3d = retilt_boxes(boxes3d, prepared.R_tilt, tilt)
            reach = iou_3d(boxes3d, np.asarray(box)[None], tilt)[:, 0] >= 0.25
            tally["best"] += bool(reach.any())
            tally["top"] += bool(reach[np.argmax(scores[rows, cls])])
    return dict(counts)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("frames", type=Path, help="a frame folder with ground truth")
    p.add_argument("--model", default="real", help="a bundled pipeline's name or a model file")
    args = p.parse_args(argv)
    counts = roi_choice(args.frames, args.model)
    print(f"{args.model} on {args.frames}: shares of each class's objects (module docstring)\n")
    print("| class | objects | covered by a RoI | its best 3D box reaches it | the top-scored RoI's does |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name in sorted(counts):
        c = counts[name]
        shares = [f"{c[k] / c['objects']:.0%}" for k in FIELDS[1:]]
        print(f"| {name} | {c['objects']} | " + " | ".join(shares) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
