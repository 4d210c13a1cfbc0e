"""a3d-eval: score a detections file against a folder's ground truth, under a named protocol.

    a3d-eval FOLDER --detections detections.jsonl [more.jsonl ...] [--protocol paper|authors|sunrgbd|all]
             [--out DIR] [--nms 0.3 | --no-nms] [--iou 0.25 0.5]

Prints the protocol's header and a table (per class: #GT, #det, AP at each IoU threshold, in
percent; then the mAP over the protocol's classes and over those with ground truth) and, with
``--out``, writes DIR/eval.json and DIR/pr_curves.png atomically. ``--protocol all`` scores under
each protocol in turn, prints each table and then their APs at the primary threshold side by side,
and writes DIR/PROTOCOL/eval.json and pr_curves.png. The protocols are defined in
``a3d.runtime.evaluation.protocols`` and the metric is ``a3d.runtime.evaluation.metric`` (see their
docstrings). ``--nms`` / ``--no-nms`` override the protocol's 2D NMS threshold (said in the header).
After the tables, the angle between each line's gravity and the ground truth's
(a3d.runtime.evaluation.gravity_report: the mAP cannot see it).

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

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.gravity_report import gravity_report
from a3d.runtime.evaluation.metric import (
    IOU_THRESHOLDS,
    NMS_IOU,
    PROTOCOL_NMS,
    EvalConfig,
    EvalResult,
    FrameTruth,
    evaluate,
)
from a3d.runtime.evaluation.pr_plot import draw_pr_curves
from a3d.runtime.evaluation.protocols import PAPER, PROTOCOLS
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.detections_io import FrameDetections, read_detections
from a3d.runtime.structures.classes import CLASSES

PROG = "a3d-eval"


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument(
        "folder", type=Path, help="frame folder with NAME.gt.json and NAME.meta.json (docs/formats.md)"
    )
    p.add_argument(
        "--detections",
        type=Path,
        nargs="+",
        required=True,
        metavar="FILE",
        help="detections JSON-lines file(s) of a3d-run (several: the shards of one run, --shard K/N)",
    )
    p.add_argument("--out", type=Path, help="also write OUT/eval.json and OUT/pr_curves.png")
    p.add_argument(
        "--protocol",
        choices=[*PROTOCOLS, "all"],
        default=PAPER.name,
        help="paper (default: the paper's protocol), authors (their MATLAB release, bit for bit), "
        "sunrgbd (VoteNet/mmdetection3d, 10 classes, area AP), all (each, then side by side); "
        "see docs/evaluation.md",
    )
    nms = p.add_mutually_exclusive_group()
    nms.add_argument(
        "--nms",
        type=float,
        nargs="?",
        const=NMS_IOU,
        default=PROTOCOL_NMS,
        metavar="IOU",
        help=f"per-class 2D NMS on box2d before scoring (default: the protocol's, IoU {NMS_IOU} for paper "
        "and authors, none for sunrgbd)",
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
        help="3D IoU thresholds, the first is the primary one",
    )
    return p


def read_detection_files(paths: list[Path]) -> list[FrameDetections]:
    """The lines of several detections files (shards of one run); a frame in two is an InputError."""
    lines: list[FrameDetections] = []
    origin: dict[str, Path] = {}
    for path in paths:
        for line in read_detections(path):
            if line.frame in origin:
                raise InputError(f"{path}: frame {line.frame!r} is also in {origin[line.frame]}")
            origin[line.frame] = path
            lines.append(line)
    return lines


def select_detections(
    lines: list[FrameDetections],
    truth: dict[str, FrameTruth],
    unannotated: list[str],
    source: Path | str,
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


def protocol_header(result: EvalResult) -> str:
    """The protocol's one-line summary, with an overridden 2D NMS said as such."""
    config = result.config
    line = config.protocol.header()
    if not config.protocol_nms:
        nms = "no 2D NMS" if config.nms_iou is None else f"2D NMS {config.nms_iou:g}"
        line += f"; overridden: {nms}"
    return line


def format_table(result: EvalResult) -> str:
    """The terminal table: the protocol, per class #GT, #det, AP per threshold (percent), both mAPs."""
    thresholds = result.config.iou_thresholds
    name_w = max(len(c) for c in CLASSES) + 2
    head = f"{'class':<{name_w}}{'#GT':>7}{'#det':>9}" + "".join(f"{f'AP@{t:g}':>10}" for t in thresholds)
    lines = [protocol_header(result), head, "-" * len(head)]
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
    if result.ignored_gt or result.ignored_det:
        lines.append(
            f"ignored (classes outside the protocol's {len(result.classes)}): "
            f"{result.ignored_gt} ground-truth objects, {result.ignored_det} detections"
        )
    return "\n".join(lines)


def format_comparison(results: list[EvalResult]) -> str:
    """AP per class at the primary threshold under each protocol, side by side ('-': no ground
    truth, or a class the protocol does not score), then both mAP rows."""
    threshold = results[0].config.iou_thresholds[0]
    by_protocol = [{c.name: c for c in r.classes} for r in results]
    name_w = max(len(c) for c in CLASSES) + 2
    head = f"{'class':<{name_w}}{'#GT':>7}" + "".join(f"{r.config.protocol.name:>10}" for r in results)
    lines = [f"AP@{threshold:g} (percent) under each protocol", head, "-" * len(head)]
    for name in CLASSES:
        scored = [classes.get(name) for classes in by_protocol]
        num_gt = next(c.num_gt for c in scored if c is not None)
        aps = "".join(f"{100 * c.ap[threshold]:>10.1f}" if c and c.present else f"{'-':>10}" for c in scored)
        lines.append(f"{name:<{name_w}}{num_gt:>7}{aps}")
    lines.append("-" * len(head))
    for label, fn in (
        ("mAP, all classes", EvalResult.map_all),
        ("mAP, classes with GT", EvalResult.map_present),
    ):
        lines.append(f"{label:<{name_w + 7}}" + "".join(f"{100 * fn(r, threshold):>10.1f}" for r in results))
    lines.append(
        "classes per protocol: " + ", ".join(f"{r.config.protocol.name} {len(r.classes)}" for r in results)
    )
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
            **result.config.protocol.describe(),
            "iou_thresholds": list(thresholds),
            "primary_iou": thresholds[0],
            "nms_iou": result.config.nms_iou,
            "nms_overridden": not result.config.protocol_nms,
            "matching": "greedy by descending score over the set, max-IoU ground truth, duplicates false",
        },
        "ignored_outside_protocol": {"ground_truth": result.ignored_gt, "detections": result.ignored_det},
        "map": {
            key[t]: {"all_classes": result.map_all(t), "present_classes": result.map_present(t)}
            for t in thresholds
        },
        "present_classes": present,
        "absent_classes": result.absent_classes,
        "classes": classes,
    }


def _write_outputs(result: EvalResult, out: Path, inputs: dict) -> None:
    """OUT/eval.json and OUT/pr_curves.png, each written atomically; OSError propagates."""
    report = json.dumps(eval_report(result, inputs), indent=1)
    ok, png = cv2.imencode(".png", draw_pr_curves(result))
    if not ok:
        raise RuntimeError("OpenCV could not encode the PR-curve PNG")
    atomic_write_bytes(out / "eval.json", report.encode("utf-8"))
    atomic_write_bytes(out / "pr_curves.png", png.tobytes())


@command(PROG)
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    nms_given = args.nms is not None and args.nms != PROTOCOL_NMS
    if any(not 0.0 < t <= 1.0 for t in args.iou) or (nms_given and not 0.0 < args.nms <= 1.0):
        parser.error("IoU thresholds (--iou, --nms) must be in (0, 1]")
    if len(set(args.iou)) != len(args.iou):
        parser.error("--iou thresholds must be distinct")
    truth, unannotated = load_truth(args.folder)  # InputError: exit 2 (command)
    lines = read_detection_files(args.detections)
    files = " + ".join(map(str, args.detections))
    detections, skipped = select_detections(lines, truth, unannotated, files, args.folder)
    if skipped:
        print(
            f"{PROG}: warning: {files}: {len(skipped)} line(s) for frames without ground truth "
            f"skipped ({', '.join(skipped[:3])}{', ...' if len(skipped) > 3 else ''})",
            file=sys.stderr,
        )
    protocols = list(PROTOCOLS.values()) if args.protocol == "all" else [PROTOCOLS[args.protocol]]
    results = [evaluate(truth, detections, EvalConfig(tuple(args.iou), args.nms, p)) for p in protocols]
    first = results[0]
    print(
        f"{len(truth)} frames with ground truth, {len(detections)} with detections, "
        f"{len(first.frames_without_detections)} without (objects missed); "
        f"{len(first.retilted_frames)} re-expressed in the ground-truth tilt frame"
    )
    for result in results:
        print(format_table(result), end="\n\n" if len(results) > 1 else "\n")
    if len(results) > 1:
        print(format_comparison(results))
    gravity = gravity_report(truth, detections)
    print(gravity.format())
    if args.out is not None:
        inputs = {
            "folder": str(args.folder.resolve()),
            "detections": [str(path.resolve()) for path in args.detections]
            if len(args.detections) > 1
            else str(args.detections[0].resolve()),
            "frames_with_gt": len(truth),
            "frames_with_detections": len(detections),
            "frames_without_detections": first.frames_without_detections,
            "skipped_frames_without_gt": skipped,
            "retilted_frames": first.retilted_frames,
            "gravity": gravity.summary(),
        }
        outs = [args.out / r.config.protocol.name for r in results] if len(results) > 1 else [args.out]
        try:
            for result, out in zip(results, outs, strict=True):
                _write_outputs(result, out, inputs)
        except OSError as e:
            raise InputError(f"{args.out}: cannot write ({e.strerror or e})") from None
        for out in outs:
            print(f"wrote {out / 'eval.json'} and {out / 'pr_curves.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
