"""False positives: detections scoring >= 0.5 per frame on frames with no labelled object at all.

    .venv/bin/a3d-synth out/fp --frames 20 --seed 11 --world real --empty-share 1 --split test=1
    .venv/bin/python -m bench.false_positives out/fp/test --model runtime/models/live.onnx [--threshold 0.5]
    .venv/bin/python -m bench.false_positives FOLDER --detections detections.jsonl

mAP says nothing about frames with nothing to find; a model that calls every cabinet a bookshelf
loses little mAP on rooms of the 19 classes and is useless in a real one. This counts, on the
frames of FOLDER whose ground truth lists no object (frames without a ground-truth file are
left out: nothing says they are empty), the detections at or above the threshold: per frame
(mean and maximum), the share of frames with any, and per class. Beside it, over every annotated
frame, how many detections reach the threshold and which share of them is right (3D IoU >= 0.25,
a3d-eval's matching): what the threshold means to a user, and what the others are: a box of the
right class too far off (3D IoU above 0 but below 0.25 with an object of its class; a duplicate
of a matched object counts with the right ones here), on an object of another class (3D IoU > 0.1
with it), or on no labelled object at all (clutter, walls, floor). Detections come from
``--detections`` (the README detections format, e.g. a3d-run's output) or from running
``a3d-run --headless`` with ``--model`` (written to OUT, default FOLDER/../false_positives.jsonl).
Prints the report and writes it as JSON next to the detections (``.report.json``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from a3d.runtime.evaluation.metric import EvalConfig, FrameTruth, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import FrameDetections, read_detections
from a3d.runtime.sources.folder import list_frames, read_ground_truth
from a3d.runtime.structures.geometry import iou_3d

IOU = 0.25
OTHER_CLASS_IOU = 0.1

BIN = Path(sys.executable).parent


def empty_frames(folder: Path) -> list[str]:
    """Names of the frames of ``folder`` whose ground truth lists no object."""
    names = []
    for ref in list_frames(folder):
        gt = read_ground_truth(ref) if ref.gt_path is not None else None
        if gt is not None and len(gt) == 0:
            names.append(ref.name)
    return names


def by_frame(detections: Path) -> dict[str, FrameDetections]:
    """A detections file's lines by frame name, read once for every count below."""
    return {d.frame: d for d in read_detections(detections)}


def count_false_positives(
    folder: Path, lines: dict[str, FrameDetections], threshold: float = 0.5
) -> dict | None:
    """The report (module docstring) of the detections on the empty frames of ``folder``; None
    when it has none. An empty frame missing from the detections is an error (a failed frame)."""
    empty = empty_frames(folder)
    if not empty:
        return None
    missing = [name for name in empty if name not in lines]
    if missing:
        raise ValueError(f"no detections line for {len(missing)} empty frames, e.g. {missing[0]}")
    counts, classes = [], Counter()
    for name in empty:
        det = lines[name]
        keep = det.scores >= threshold
        counts.append(int(keep.sum()))
        classes.update(c for c, k in zip(det.classes, keep, strict=True) if k)
    return {
        "threshold": threshold,
        "empty_frames": len(empty),
        "detections": sum(counts),
        "per_frame": sum(counts) / len(empty),
        "max_per_frame": max(counts),
        "frames_with_any": sum(c > 0 for c in counts) / len(empty),
        "by_class": dict(classes.most_common()),
    }


def right_share(folder: Path, lines: dict[str, FrameDetections], threshold: float = 0.5) -> dict:
    """Detections >= ``threshold`` on the annotated frames of ``folder`` and how many are right."""
    truth, _ = load_truth(folder)
    found = {name: d for name, d in lines.items() if name in truth}
    result = evaluate(truth, found, EvalConfig(iou_thresholds=(IOU,)))
    kept = [c.true_positives(IOU)[c.scores >= threshold] for c in result.classes]
    right, total = sum(int(k.sum()) for k in kept), sum(len(k) for k in kept)
    share = right / total if total else None
    kinds = Counter(
        _kind(truth[name], c, box) for name, d in found.items()
        for c, score, box in zip(d.class_ids, d.scores, d.boxes3d, strict=True) if score >= threshold
    )  # fmt: skip
    return {"frames": len(truth), "detections": total, "right": right, "share": share, "iou": IOU,
            "kinds": {k: kinds[k] for k in KINDS}}  # fmt: skip


KINDS = ("right_or_duplicate", "same_class_poor_box", "other_class_object", "no_labelled_object")


def _kind(truth: FrameTruth, class_id: int, box: np.ndarray) -> str:
    """Which of KINDS one detection is, by its best 3D IoU with the frame's objects."""
    same = truth.boxes3d[truth.class_ids == class_id]
    best = iou_3d(box[None], same, truth.R_tilt).max() if len(same) else 0.0
    if best >= IOU:
        return KINDS[0]
    if best > 0.0:
        return KINDS[1]
    other = iou_3d(box[None], truth.boxes3d, truth.R_tilt).max() if len(truth.boxes3d) else 0.0
    return KINDS[2] if other > OTHER_CLASS_IOU else KINDS[3]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a frame folder with ground truth")
    parser.add_argument("--model", type=Path, help="run this ONNX model with a3d-run --headless")
    parser.add_argument("--detections", type=Path, help="detections already made (instead of --model)")
    parser.add_argument(
        "--out", type=Path, help="where a3d-run writes (default FOLDER/../false_positives.jsonl)"
    )
    parser.add_argument("--threshold", type=float, default=0.5)
    args = parser.parse_args(argv)
    if (args.model is None) == (args.detections is None):
        parser.error("give exactly one of --model and --detections")
    detections = args.detections
    if args.model is not None:
        detections = args.out or args.folder.parent / "false_positives.jsonl"
        command = [str(BIN / "a3d-run"), str(args.folder), "--model", str(args.model), "--output",
                   str(detections), "--headless"]  # fmt: skip
        print("$", " ".join(command), flush=True)
        if subprocess.run(command).returncode != 0:
            print(f"false_positives: a3d-run failed on {args.folder}", file=sys.stderr)
            return 1
    try:
        lines = by_frame(detections)
        report = count_false_positives(args.folder, lines, args.threshold)
        if report is not None:
            report["all_frames"] = right_share(args.folder, lines, args.threshold)
    except (OSError, ValueError) as e:
        print(f"false_positives: {detections}: {e}", file=sys.stderr)
        return 1
    if report is None:
        print(f"false_positives: {args.folder}: no frame with an empty ground truth", file=sys.stderr)
        return 1
    detections.with_suffix(".report.json").write_text(json.dumps(report, indent=1))
    print(json.dumps(report, indent=1))
    every = report["all_frames"]
    share = "none" if every["share"] is None else f"{100 * every['share']:.0f}% right"
    others = ", ".join(f"{k} {n}" for k, n in every["kinds"].items() if k != KINDS[0])
    print(f"detections >= {args.threshold} per empty frame: {report['per_frame']:.2f} "
          f"over {report['empty_frames']} frames (max {report['max_per_frame']}); over all "
          f"{every['frames']} frames {every['detections']} detections >= {args.threshold}, "
          f"{share}; the others: {others}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
