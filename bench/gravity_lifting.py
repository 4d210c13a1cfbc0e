"""Accuracy and speed of the runtime front end on frames with ground truth.

Frames come from a folder in the frame format (e.g. a3d-synth's test split) or are rendered on
the fly by a3d.synth.generate_frame from held-out seeds (`--synth FIRST COUNT`), which also
gives each object's exact visible fraction. Per frame: hole filling, surface normals, gravity
(R_tilt) estimation, lifting of the ground-truth instance masks to initial 3D boxes (docs/conventions.md
"Proposals and 3D box initialisation"), and the lifting of the frame's real proposals
(a3d.runtime.frontend.proposals) for timing.

Reports: gravity angle error vs the frame's R_tilt (median, 95th percentile; targets <= 1.5 and
<= 5 degrees); initial-centre distance to the true amodal centre (target median <= 15 cm) for
the fully visible objects (rendered: visibility >= 0.95 and not cut by the border; folder: the
visible 2D box covers >= 95% of the amodal 2D box, a proxy blind to occlusion inside the box)
and for all objects; the 3D IoU of the initial boxes built with the class mean sizes (over the
objects seen); per-stage wall and CPU times (median and max, ms).

With proposals, also the "without 3D regression" reference of issue 4: the initial boxes of the
real proposals (lifted centre, class mean size, theta 0) labelled by an oracle, i.e. each
proposal with 2D IoU >= 0.5 to a visible ground-truth box takes that object's class and its
IoU as score, then per-class 2D NMS 0.3 and a3d.runtime.evaluation.metric's mAP@0.25. The mean sizes
are those of the evaluated frames' own ground truth (an oracle too), so this bounds what the
network's classifier could reach on these proposals without any 3D regression.

    .venv/bin/python -m bench.gravity_lifting --synth 100000 30
    .venv/bin/python -m bench.gravity_lifting --synth 100000 120 --per-class
    .venv/bin/python -m bench.gravity_lifting --folder /tmp/synth_small/test [--limit 50]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from a3d.runtime.evaluation.metric import FrameTruth, evaluate
from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.gravity import estimate_gravity
from a3d.runtime.frontend.lifting import initial_boxes, lift
from a3d.runtime.frontend.normals import surface_normals
from a3d.runtime.frontend.proposals import propose
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.sources.folder import (
    list_frames,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
)
from a3d.runtime.structures.boxes import boxes_array
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, iou_2d, iou_3d
from bench.paper_table2 import PAPER_AP

FULLY_VISIBLE = 0.95


@dataclass
class BenchFrame:
    color: np.ndarray
    depth: np.ndarray
    K: Intrinsics
    R_tilt: np.ndarray | None
    gt: GroundTruth | None
    instances: np.ndarray | None
    fully_visible: np.ndarray | None  # (N,) bool per gt object


def folder_frames(folder: Path, limit: int) -> Iterator[BenchFrame]:
    refs = list_frames(folder)[: limit or None]
    folder_k = read_folder_intrinsics(folder)
    for ref in refs:
        frame = read_frame(ref, folder_k)
        gt = read_ground_truth(ref)
        full = None
        if gt is not None and len(gt):
            full = np.diag(iou_2d(gt.boxes2d_visible, gt.boxes2d_amodal)) >= FULLY_VISIBLE
        yield BenchFrame(
            frame.color, frame.depth, frame.intrinsics, frame.R_tilt, gt, read_instances(ref), full
        )


def synth_frames(first: int, count: int) -> Iterator[BenchFrame]:
    from a3d.synth.scene import generate_frame

    for seed in range(first, first + count):
        f = generate_frame(seed)
        records = [r for r in f.objects if r.annotated]  # in gt order (instance ids 1..N)
        full = np.array([r.visibility >= FULLY_VISIBLE and not r.truncated for r in records], bool)
        yield BenchFrame(f.color, f.depth, f.intrinsics, f.R_tilt, f.gt, f.instances, full)


def _timed(times: dict[str, list[tuple[float, float]]], stage: str, fn, *args):
    """Run fn(*args), recording (wall, process CPU) seconds: on a shared machine CPU time is the
    steadier measure of the work itself."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args)
    times.setdefault(stage, []).append((time.perf_counter() - t0, time.process_time() - c0))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--folder", type=Path, help="frames with NAME.meta.json R_tilt, gt and instances")
    source.add_argument("--synth", type=int, nargs=2, metavar=("FIRST", "COUNT"), help="render these seeds")
    parser.add_argument("--limit", type=int, default=0, help="folder: at most this many frames (0 = all)")
    parser.add_argument("--no-proposals", action="store_true", help="skip proposals and their lifting")
    parser.add_argument("--per-class", action="store_true", help="a row per class, beside the paper's")
    args = parser.parse_args()
    frames = synth_frames(*args.synth) if args.synth else folder_frames(args.folder, args.limit)

    times: dict[str, list[tuple[float, float]]] = {}
    n_proposals: list[int] = []
    grav_err: list[float] = []
    statuses: Counter[str] = Counter()
    objects = []  # (class id, fully visible, centre distance, initial centre, gt box, R_tilt)
    oracle = {}  # frame -> (truth, class ids, scores, 2D boxes, centres, R_tilt) of labelled proposals
    n_frames = 0
    for fr in frames:
        n_frames += 1
        filled = _timed(times, "fill_depth", fill_depth, fr.depth)
        _timed(times, "surface_normals", surface_normals, fr.depth, fr.K)
        est = _timed(times, "gravity", estimate_gravity, fr.depth, fr.K)
        statuses[est.status] += 1
        if fr.R_tilt is not None:  # row 1 of an R_tilt is its gravity direction (camera frame)
            grav_err.append(np.degrees(np.arccos(np.clip(est.gravity @ fr.R_tilt[1], -1.0, 1.0))))
        if fr.gt is not None and fr.instances is not None and len(fr.gt):
            # The instance map is a superpixel map whose superpixel k is exactly object k's mask.
            labels = fr.instances.astype(np.int32)
            present = np.flatnonzero(np.isin(fr.gt.instance_ids, labels))
            masks = SimpleNamespace(
                superpixels=labels, indptr=np.arange(len(present) + 1), indices=fr.gt.instance_ids[present]
            )
            lifted = _timed(times, "lift_gt_masks", lift, masks, fr.depth, filled, fr.K)
            for j, i in enumerate(present):
                if lifted.valid[j]:
                    box = fr.gt.boxes3d[i]
                    dist = float(np.linalg.norm(lifted.centers[j] - box[:3]))
                    objects.append(
                        (fr.gt.class_ids[i], fr.fully_visible[i], dist, lifted.centers[j], box, fr.R_tilt)
                    )
        if not args.no_proposals:
            props = _timed(times, "propose", propose, fr.color, filled, fr.K)
            lifted = _timed(times, "lift_proposals", lift, props, fr.depth, filled, fr.K)
            n_proposals.append(len(props))
            if fr.gt is not None:
                oracle[f"{n_frames:06d}"] = _oracle_labels(fr, props.boxes, lifted, est.R_tilt)

    print(f"{n_frames} frames from {args.folder or f'a3d.synth seeds {args.synth[0]}+{args.synth[1]}'}")
    if grav_err:
        e = np.asarray(grav_err)
        print(
            f"gravity: angle error median {np.median(e):.2f} deg, p95 {np.percentile(e, 95):.2f} deg, "
            f"max {e.max():.2f} deg (targets <= 1.5, <= 5); status {dict(statuses)}"
        )
    if objects:
        cls = np.array([o[0] for o in objects])
        full = np.array([o[1] for o in objects], bool)
        dist = np.array([o[2] for o in objects])
        mean_sizes = np.zeros((NUM_CLASSES, 3))
        for c in np.unique(cls):
            mean_sizes[c] = np.mean([o[4][3:6] for o in objects if o[0] == c], axis=0)
        ious = np.array(
            [iou_3d(initial_boxes(o[3][None], mean_sizes)[:, o[0]], o[4][None], o[5])[0, 0] for o in objects]
        )
        for name, sel in (("fully visible", full), ("all objects", np.ones_like(full))):
            if sel.any():
                print(
                    f"lifting, {name} ({int(sel.sum())}): centre distance median "
                    f"{100 * np.median(dist[sel]):.1f} cm, p90 {100 * np.percentile(dist[sel], 90):.1f} cm "
                    f"(target median <= 15 cm); initial-box 3D IoU median {np.median(ious[sel]):.3f}, "
                    f">= 0.25: {np.mean(ious[sel] >= 0.25):.0%}"
                )
    if n_proposals:
        print(f"proposals per frame: median {np.median(n_proposals):.0f}, max {max(n_proposals)}")
    if oracle and objects:
        result = _oracle_map(oracle, mean_sizes)
        present = sum(c.present for c in result.classes)
        print(
            f"without 3D regression (oracle class, initial boxes of the real proposals): mAP@0.25 "
            f"{100 * result.map_all(0.25):.1f} over 19 classes, {100 * result.map_present(0.25):.1f} "
            f"over the {present} present"
        )
        if args.per_class:
            _print_per_class(cls, ious, np.array([o[4] for o in objects]), result)
    for stage, t in times.items():
        wall, cpu = 1e3 * np.asarray(t).T
        print(
            f"time {stage:16s} wall median {np.median(wall):6.1f} ms, max {wall.max():6.1f} ms; "
            f"cpu median {np.median(cpu):6.1f} ms, max {cpu.max():6.1f} ms"
        )


def _print_per_class(cls: np.ndarray, ious: np.ndarray, boxes: np.ndarray, result) -> None:
    """Why initial boxes score what they score, class by class: the spread of the true sizes
    (coefficient of variation of the volume), how far the true yaw is from the initial theta 0,
    the ground-truth masks' initial-box hit rate and the oracle AP, beside Table 2's
    "img+d+ct-3dreg" row (NYUv2, scored with the network's own classifier, not an oracle)."""
    print("class            n  vol cv |yaw| med IoU>=.25 oracle AP  paper")
    for c, (name, paper) in enumerate(zip(CLASSES, PAPER_AP["no-3dreg"], strict=True)):
        sel = cls == c
        if not sel.any():
            continue
        vol = np.prod(boxes[sel, 3:6], axis=1)
        print(
            f"{name:13s} {int(sel.sum()):4d} {vol.std() / vol.mean():7.2f} "
            f"{np.degrees(np.median(np.abs(boxes[sel, 6]))):8.0f}° {np.mean(ious[sel] >= 0.25):8.0%} "
            f"{100 * result.classes[c].ap[0.25]:9.1f} {paper:6.1f}"
        )


def _oracle_labels(fr: BenchFrame, boxes: np.ndarray, lifted, R_est: np.ndarray) -> tuple:
    """The proposals that overlap a visible box by >= 0.5, with that object's class and IoU."""
    R_tilt = fr.R_tilt if fr.R_tilt is not None else R_est  # what the runtime would use
    truth = FrameTruth(fr.gt.class_ids, fr.gt.boxes3d, R_tilt)  # the boxes' theta is in the frame's R_tilt
    if not len(fr.gt) or not len(boxes):
        return truth, np.zeros(0, int), np.zeros(0), np.zeros((0, 4)), np.zeros((0, 3)), R_tilt
    overlaps = iou_2d(boxes, fr.gt.boxes2d_visible)
    best = overlaps.argmax(1)
    score = overlaps.max(1)
    keep = (score >= 0.5) & lifted.valid
    return truth, fr.gt.class_ids[best[keep]], score[keep], boxes[keep], lifted.centers[keep], R_tilt


def _oracle_map(oracle: dict, mean_sizes: np.ndarray):
    truths, detections = {}, {}
    for name, (truth, class_ids, scores, boxes2d, centers, R_tilt) in oracle.items():
        boxes3d = initial_boxes(centers, mean_sizes)[np.arange(len(class_ids)), class_ids]
        truths[name] = truth
        detections[name] = FrameDetections(name, R_tilt, class_ids, scores, boxes2d, boxes_array(boxes3d))
    return evaluate(truths, detections)


if __name__ == "__main__":
    main()
