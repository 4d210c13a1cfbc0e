"""Which part of a 3D box loses an object: its place across the floor, its height, its size or its yaw.

    .venv/bin/python -m bench.box_errors FRAMES --detections detections.jsonl [--min-score 0.05]

For every ground-truth object of FRAMES (a frame folder with ground truth), its class's detection
in the detections file (a3d-run's output) that overlaps it most in 3D, among those scoring
``--min-score`` or more. Per class:

- *found*: that detection reaches the object (3D IoU >= 0.25): where the class's precision-recall
  curve can end at best (no ranking finds more);
- *found with the truth's ...*: the share it would reach with one part of its box set to the
  object's: its centre across the floor (the tilt frame's x and z), its height (y), its size, or
  its yaw; the part whose fix finds the most is what loses the class's objects;
- for the objects not found that a detection of their class overlaps at all: its centre's error
  across the floor, along the camera's ray to the object (negative: nearer the camera) and across
  it, median and the 10th and 90th percentiles, and the object's distance from the camera.

Last, mAP@0.25 over the classes present, as written and with every detection moved to the centre
across the floor of the nearest object of its class (within ``PLACE_REACH_M``): what the run would
score were every box in its place, its size, yaw and score its own.

bench.roi_choice asks the same of a model's RoIs before selection; this asks it of what a run
wrote, after every step of docs/real-rooms.md.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import defaultdict
from pathlib import Path

import numpy as np

from a3d.runtime.evaluation.metric import EvalConfig, FrameTruth, evaluate, retilt_boxes
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import FrameDetections, read_detections
from a3d.runtime.structures.boxes import CENTER, SIZE, THETA
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import iou_3d

IOU = 0.25
PLACE_REACH_M = 1.0
PARTS = ("across the floor", "height", "size", "yaw")


def with_truths_part(box: np.ndarray, truth: np.ndarray, part: str, R_tilt: np.ndarray) -> np.ndarray:
    """``box`` (7,) with one ``part`` (of PARTS) set to ``truth``'s (both camera-frame centres, yaw
    in the tilt frame of ``R_tilt``)."""
    out = np.array(box, np.float64, copy=True)
    if part in PARTS[:2]:
        axes = [0, 2] if part == PARTS[0] else [1]
        centre = R_tilt @ out[CENTER]
        centre[axes] = (R_tilt @ truth[CENTER])[axes]
        out[CENTER] = R_tilt.T @ centre
    elif part == "size":
        out[SIZE] = truth[SIZE]
    else:
        out[THETA] = truth[THETA]
    return out


def ray_errors(box: np.ndarray, truth: np.ndarray, R_tilt: np.ndarray) -> tuple[float, float, float]:
    """The box centre's error across the floor along the camera's ray to the truth's centre
    (negative: nearer) and across that ray, and the truth's distance across the floor (metres)."""
    error, centre = R_tilt @ (box[CENTER] - truth[CENTER]), R_tilt @ truth[CENTER]
    ray = centre[[0, 2]]
    distance = float(np.linalg.norm(ray))
    ray = ray / max(distance, 1e-9)
    return float(error[[0, 2]] @ ray), float(error[2] * ray[0] - error[0] * ray[1]), distance


def read(frames: Path, detections: Path) -> tuple[dict[str, FrameTruth], dict[str, FrameDetections]]:
    """FRAMES' ground truth and the detections file's lines of its annotated frames, by frame."""
    truth, _ = load_truth(frames)
    return truth, {d.frame: d for d in read_detections(detections) if d.frame in truth}


def box_errors(
    truth: dict[str, FrameTruth], lines: dict[str, FrameDetections], min_score: float = 0.05
) -> dict[str, dict]:
    """Per class: ``objects``, ``found``, ``fixed`` (part -> count) and ``missed`` (rows of
    ``ray_errors`` for the objects not found that a detection of their class overlaps at all)."""
    out: dict[str, dict] = defaultdict(lambda: {"objects": 0, "found": 0, "fixed": dict.fromkeys(PARTS, 0),
                                                "missed": []})  # fmt: skip
    for name, frame in truth.items():
        line = lines.get(name)
        R = np.asarray(frame.R_tilt, np.float64)
        if line is not None:
            kept = line.scores >= min_score
            classes, boxes = line.class_ids[kept], retilt_boxes(line.boxes3d[kept], line.R_tilt, R)
        for class_id, gt in zip(frame.class_ids, np.asarray(frame.boxes3d, np.float64), strict=True):
            tally = out[CLASSES[class_id]]
            tally["objects"] += 1
            if line is None or not (classes == class_id).any():
                continue
            mine = boxes[classes == class_id]
            overlaps = iou_3d(mine, gt[None], R)[:, 0]
            box = mine[int(np.argmax(overlaps))]
            found = overlaps.max() >= IOU
            tally["found"] += bool(found)
            for part in PARTS:
                fixed = iou_3d(with_truths_part(box, gt, part, R)[None], gt[None], R)[0, 0]
                tally["fixed"][part] += bool(fixed >= IOU)
            if not found and overlaps.max() > 0:
                tally["missed"].append(ray_errors(box, gt, R))
    return dict(out)


def placed(truth: FrameTruth, line: FrameDetections) -> FrameDetections:
    """``line`` with each detection moved to the centre across the floor of the nearest object of
    its class in ``truth`` (within ``PLACE_REACH_M``), in the truth's tilt frame."""
    R = np.asarray(truth.R_tilt, np.float64)
    boxes = retilt_boxes(line.boxes3d, line.R_tilt, R)
    objects, gt = np.asarray(truth.class_ids), np.asarray(truth.boxes3d, np.float64)
    for i, box in enumerate(boxes):
        mine = gt[objects == line.class_ids[i]]
        if len(mine):
            apart = np.linalg.norm((mine[:, CENTER] - box[CENTER]) @ R.T[:, [0, 2]], axis=1)
            if apart.min() <= PLACE_REACH_M:
                boxes[i] = with_truths_part(box, mine[int(np.argmin(apart))], PARTS[0], R)
    return dataclasses.replace(line, R_tilt=R, boxes3d=boxes, corners=None)


def map_as_placed(truth: dict[str, FrameTruth], lines: dict[str, FrameDetections]) -> tuple[float, float]:
    """mAP@0.25 over the classes present: the detections as written, and ``placed``."""
    config = EvalConfig(iou_thresholds=(IOU,))
    moved = {name: placed(truth[name], line) for name, line in lines.items()}
    written, placed_all = (evaluate(truth, d, config).map_present(IOU) for d in (lines, moved))
    return written, placed_all


def _spread(values: list[float]) -> str:
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return f"{p50:+.2f} ({p10:+.2f} to {p90:+.2f})"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("frames", type=Path, help="a frame folder with ground truth")
    p.add_argument("--detections", type=Path, required=True, help="a3d-run's detections of those frames")
    p.add_argument("--min-score", type=float, default=0.05)
    args = p.parse_args(argv)
    truth, lines = read(args.frames, args.detections)
    counts = box_errors(truth, lines, args.min_score)
    print(f"{args.detections} on {args.frames}, detections scoring >= {args.min_score}: "
          "shares of each class's objects (module docstring)\n")  # fmt: skip
    print("| class | objects | found | " + " | ".join(f"with the truth's {part}" for part in PARTS) + " |")
    print("| --- " + "| ---: " * (2 + len(PARTS)) + "|")
    for name in sorted(counts):
        c = counts[name]
        shares = [c["found"], *c["fixed"].values()]
        print(f"| {name} | {c['objects']} | " + " | ".join(f"{s / c['objects']:.0%}" for s in shares) + " |")
    print("\n| class | not found | centre along the ray, m | across it, m | distance, m |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name in sorted(counts):
        missed = counts[name]["missed"]
        if missed:
            along, across, distance = zip(*missed, strict=True)
            print(f"| {name} | {len(missed)} | {_spread(along)} | {_spread(across)} | {_spread(distance)} |")
    written, moved = map_as_placed(truth, lines)
    print(
        f"\nmAP@0.25 over the classes present: {100 * written:.1f} as written, {100 * moved:.1f} with "
        f"every detection at the nearest object of its class across the floor (within {PLACE_REACH_M:g} m)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
