"""a3d-eval: score a detections file against a folder's ground truth (the paper's protocol).

    a3d-eval FOLDER --detections detections.jsonl [--out DIR] [--nms 0.3 | --no-nms] [--iou 0.25 0.5]

Prints a table (per class: #GT, #det, AP at each IoU threshold, in percent; then the mAP over
all 19 classes and over the classes with ground truth), then the angle between each line's
gravity and the ground truth's (a3d.runtime.evaluation.gravity_report: the mAP cannot see it)
and, with ``--out``, writes DIR/eval.json and DIR/pr_curves.png atomically. The metric is
``a3d.runtime.evaluation.metric`` (see its docstring).

The test set is every frame of FOLDER that has ``NAME.gt.json``; a frame with ground truth and no
detection line has all its objects missed. A detection line for a frame of FOLDER without
ground truth is skipped with a warning (unannotated frames are not part of the test set); a
line for a frame that is not in FOLDER at all is an error (the wrong folder or file).
Exit codes: 0 ok, 2 usage or bad input (a one-line message naming the file).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2

from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.gravity_report import gravity_report
from a3d.runtime.evaluation.metric import (
    IOU_THRESHOLDS,
    NMS_IOU,
    EvalConfig,
    EvalResult,
    FrameTruth,
    evaluate,
)
from a3d.runtime.evaluation.pr_plot import draw_pr_curves
from a3d.runtime.io.detections_io import FrameDetections, atomic_write_bytes, read_detections
from a3d.runtime.sources.folder import list_frames, read_ground_truth, read_meta

PROG = "a3d-eval"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="frame folder with NAME.gt.json and NAME.meta.json (README)")
    p.add_argument("--detections", type=Path, required=True, help="detections JSON-lines file (a3d-run)")
    p.add_argument("--out", type=Path, help="also write OUT/eval.json and OUT/pr_curves.png")
    nms = p.add_mutually_exclusive_group()
    nms.add_argument(
        "--nms",
        type=float,
        nargs="?",
        const=NMS_IOU,
        default=NMS_IOU,
        metavar="IOU",
        help=f"per-class 2D NMS on box2d before scoring (default: on, IoU {NMS_IOU})",
    )
    nms.add_argument(
        "--no-nms", dest="nms", action="store_const", const=None, help="score detections as given"
    )
    p.add_argument(
        "--iou",
        type=float,
        nargs="+",
        default=list(IOU_THRESHOLDS),
        metavar="T",
        help="3D IoU thresholds, the first is the primary one (default: 0.25 0.5)",
    )
    return p


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


def select_detections(
    lines: list[FrameDetections],
    truth: dict[str, FrameTruth],
    unannotated: list[str],
    source: Path,
    folder: Path,
) -> tuple[dict[str, FrameDetections], list[str]]:
    """The lines of annotated frames, and the unannotated frames whose lines are skipped."""
    known = set(unannotated)
    foreign = [d.frame for d in lines if d.frame not in truth and d.frame not in known]
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise InputError(f"{source}: frame {foreign[0]!r}{more} is not a frame of {folder}")
    skipped = [d.frame for d in lines if d.frame in known]
    return {d.frame: d for d in lines if d.frame in truth}, skipped


def format_table(result: EvalResult) -> str:
    """The terminal table: per class #GT, #det, AP per threshold (percent), then both mAP rows."""
    thresholds = result.config.iou_thresholds
    name_w = max(len(c.name) for c in result.classes) + 2
    head = f"{'class':<{name_w}}{'#GT':>7}{'#det':>9}" + "".join(f"{f'AP@{t:g}':>10}" for t in thresholds)
    lines = [head, "-" * len(head)]
    for c in result.classes:
        aps = "".join(f"{100 * c.ap[t]:>10.1f}" if c.present else f"{'-':>10}" for t in thresholds)
        lines.append(f"{c.name:<{name_w}}{c.num_gt:>7}{c.num_det:>9}{aps}")
    lines.append("-" * len(head))
    n_present = sum(c.present for c in result.classes)
    rows = (
        (f"mAP, all {len(result.classes)} classes", result.map_all),
        (f"mAP, {n_present} classes with GT", result.map_present),
    )
    label_w = name_w + 16
    for label, fn in rows:
        lines.append(f"{label:<{label_w}}" + "".join(f"{100 * fn(t):>10.1f}" for t in thresholds))
    if result.absent_classes:
        lines.append("no ground truth (AP 0 in the all-classes mAP): " + ", ".join(result.absent_classes))
    return "\n".join(lines)


def eval_report(result: EvalResult, inputs: dict) -> dict:
    """The content of eval.json. APs are fractions in [0, 1]; keys of thresholds are like "0.25".

    Per class and threshold, ``curve`` holds recall, precision and score at each true positive and
    at the last detection: the corners of the curve, from which the interpolated curve and the AP
    follow exactly (the full per-detection arrays would be ~10^5 rows per class).
    """
    thresholds = result.config.iou_thresholds
    key = {t: f"{t:g}" for t in thresholds}
    classes = {}
    for c in result.classes:
        curves = {}
        for t in thresholds:
            corners = c.curve_corners(t).round(6)
            curves[key[t]] = {
                "recall": corners[:, 0].tolist(),
                "precision": corners[:, 1].tolist(),
                "score": corners[:, 2].tolist(),
            }
        classes[c.name] = {
            "num_gt": c.num_gt,
            "num_det": c.num_det,
            "present": c.present,
            "ap": {key[t]: c.ap[t] for t in thresholds},
            "curve": curves,
        }
    present = [c.name for c in result.classes if c.present]
    return {
        "inputs": inputs,
        "protocol": {
            "iou_thresholds": list(thresholds),
            "primary_iou": thresholds[0],
            "nms_iou": result.config.nms_iou,
            "ap": "11-point interpolated (recall 0, 0.1, ..., 1)",
            "matching": "greedy by descending score over the set, max-IoU ground truth, duplicates false",
        },
        "map": {
            key[t]: {"all_classes": result.map_all(t), "present_classes": result.map_present(t)}
            for t in thresholds
        },
        "present_classes": present,
        "absent_classes": result.absent_classes,
        "classes": classes,
    }


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if any(not 0.0 < t <= 1.0 for t in args.iou) or (args.nms is not None and not 0.0 < args.nms <= 1.0):
        _parser().error("IoU thresholds (--iou, --nms) must be in (0, 1]")
    if len(set(args.iou)) != len(args.iou):
        _parser().error("--iou thresholds must be distinct")
    try:
        truth, unannotated = load_truth(args.folder)
        lines = read_detections(args.detections)
        detections, skipped = select_detections(lines, truth, unannotated, args.detections, args.folder)
    except InputError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    if skipped:
        print(
            f"{PROG}: warning: {args.detections}: {len(skipped)} line(s) for frames without ground truth "
            f"skipped ({', '.join(skipped[:3])}{', ...' if len(skipped) > 3 else ''})",
            file=sys.stderr,
        )
    result = evaluate(truth, detections, EvalConfig(tuple(args.iou), args.nms))
    nms = "off" if args.nms is None else f"{args.nms:g}"
    print(
        f"{len(truth)} frames with ground truth, {len(detections)} with detections, "
        f"{len(result.frames_without_detections)} without (objects missed); 2D NMS {nms}; "
        f"{len(result.retilted_frames)} re-expressed in the ground-truth tilt frame"
    )
    print(format_table(result))
    gravity = gravity_report(truth, detections)
    print(gravity.format())
    if args.out is not None:
        inputs = {
            "folder": str(args.folder.resolve()),
            "detections": str(args.detections.resolve()),
            "frames_with_gt": len(truth),
            "frames_with_detections": len(detections),
            "frames_without_detections": result.frames_without_detections,
            "skipped_frames_without_gt": skipped,
            "retilted_frames": result.retilted_frames,
            "gravity": gravity.summary(),
        }
        report = json.dumps(eval_report(result, inputs), indent=1)
        ok, png = cv2.imencode(".png", draw_pr_curves(result))
        if not ok:
            raise RuntimeError("OpenCV could not encode the PR-curve PNG")
        try:
            atomic_write_bytes(args.out / "eval.json", report.encode("utf-8"))
            atomic_write_bytes(args.out / "pr_curves.png", png.tobytes())
        except OSError as e:
            print(f"{PROG}: error: {args.out}: cannot write ({e.strerror or e})", file=sys.stderr)
            return 2
        print(f"wrote {args.out / 'eval.json'} and {args.out / 'pr_curves.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
