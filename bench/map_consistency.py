"""A label-free measure of a detector on a posed recording: its object map's consistency.

    .venv/bin/python -m bench.map_consistency FRAMES --detections det.jsonl [--min-support 3]
        [--world-boxes world_boxes.json] [--map map.json] [--json report.json]

Builds the object map (a3d.runtime.mapping.object_map) from a3d-run's detections of a posed source
FRAMES (the lines carry each frame's pose, or the pose a3d-run --map tracked where the source has
none; the frames give the intrinsics and depth that tell what each frame should have seen) and
reports, for the objects supported by at least ``--min-support`` frames, the re-detection rate,
the jitter of their observations (centre, size, yaw) and, over all mapped detections, the
spurious rate (a3d.runtime.mapping.consistency). None of it needs labels.

Where labels exist it puts them beside: the detections' mAP@0.25 on FRAMES' ground truth (the
classes present, as a3d-eval scores it), the same for the map's confirmed boxes projected back into
every frame (ObjectMap.seen_from: one fixed box per object, so no jitter between frames) and, with
``--world-boxes`` (an a3d-synth sequence's world_boxes.json), the map's own precision and recall
against the objects the ground truth annotates in at least ``--min-support`` frames, and the
centre error of the matched ones.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from a3d.runtime.evaluation.metric import EvalConfig, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.mapping.consistency import MapConsistency, against_world, map_consistency
from a3d.runtime.mapping.object_map import ObjectMap
from a3d.runtime.mapping.world import boxes_to_camera, same_boxes
from a3d.runtime.mapping.world_boxes import read_world_boxes
from a3d.runtime.sources.folder import list_frames, read_ground_truth, read_meta
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.runtime.structures.geometry import Intrinsics

IOU = 0.25


Cameras = dict[str, tuple[Intrinsics, tuple[int, int]]]  # frame -> its intrinsics and image size


def build_map(frames: Path, detections: Path) -> tuple[ObjectMap, Cameras]:
    """The object map of a detections file over its frame source, frame by frame in order, at the
    poses the lines carry (the source's, or those a3d-run --map tracked, where a lost frame has
    none; the frames' own for a file without any), and each mapped frame's camera (to project the
    map back into it)."""
    lines = {d.frame: d for d in read_detections(detections)}
    carried = any(line.pose is not None for line in lines.values())
    world_map, cameras = ObjectMap(), {}
    for loader in open_source(frames, SourceOptions(with_proposals=False)):
        if loader.name in lines:
            frame, line = loader.load(), lines[loader.name]
            pose = line.pose if carried else frame.pose
            world_map.update(line, pose, intrinsics=frame.intrinsics, depth=frame.depth)
            cameras[loader.name] = (frame.intrinsics, frame.depth.shape[:2])
    return world_map, cameras


def annotated_world_ids(frames: Path, world_boxes: Path, min_support: int) -> set[int]:
    """The world objects a3d-synth annotates in at least ``min_support`` frames of FRAMES."""
    world = read_world_boxes(world_boxes)
    counts: Counter[int] = Counter()
    for ref in list_frames(frames):
        truth, meta = read_ground_truth(ref), read_meta(ref)
        if truth is None or meta.pose is None:
            continue
        rows = same_boxes(truth.boxes3d, boxes_to_camera(world.boxes, meta.pose, meta.R_tilt))
        counts.update(int(world.ids[k]) for k in rows if k >= 0)
    return {k for k, n in counts.items() if n >= min_support}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("frames", type=Path, help="the posed frame source the detections are of")
    p.add_argument("--detections", type=Path, required=True, help="a3d-run's detections (JSON lines)")
    p.add_argument("--min-support", type=int, default=3, help="frames an object needs to be measured")
    p.add_argument(
        "--world-boxes", type=Path, help="the world's boxes (a3d-synth --sequence), to score the map"
    )
    p.add_argument("--map", type=Path, help="also write the map here")
    p.add_argument("--json", type=Path, help="write the report as JSON here")
    args = p.parse_args(argv)
    world_map, cameras = build_map(args.frames, args.detections)
    if args.map:
        world_map.write(args.map)
    measures = map_consistency(world_map, args.min_support)
    report: dict = {
        "frames_mapped": world_map.frames_mapped,
        "frames_skipped": dict(world_map.frames_skipped),
        "min_support": args.min_support,
        "objects": len(measures.objects),
        "redetection_median": measures.median("redetection"),
        "centre_jitter_m_median": measures.median("centre_jitter_m"),
        "size_jitter_median": measures.median("size_jitter"),
        "yaw_jitter_deg_median": measures.median("yaw_jitter_deg"),
        "mapped_detections": measures.detections,
        "spurious_rate": measures.spurious_rate,
        "per_object": [vars(o) for o in measures.objects],
    }
    _print_report(world_map, measures, args.min_support)
    truth = _truth(args.frames)
    if truth is not None:
        lines = {d.frame: d for d in read_detections(args.detections) if d.frame in truth}
        result = evaluate(truth, lines, EvalConfig())
        report["map_at_025_present"] = result.map_present(IOU)
        score = 100 * result.map_present(IOU)
        print(f"labelled: mAP@{IOU} (classes present) {score:.1f} on {len(truth)} frames")
        back = {name: world_map.seen_from(line, *cameras[name]) for name, line in lines.items()
                if name in cameras and line.pose is not None}  # fmt: skip
        mapped = evaluate(truth, back, EvalConfig())
        report["map_projected_at_025_present"] = mapped.map_present(IOU)
        print(f"labelled: the map's confirmed boxes projected back into each frame: mAP@{IOU} "
              f"{100 * mapped.map_present(IOU):.1f} on {len(back)} frames")  # fmt: skip
    if args.world_boxes is not None:
        seen = annotated_world_ids(args.frames, args.world_boxes, args.min_support)
        accuracy = against_world(world_map, read_world_boxes(args.world_boxes), args.min_support, IOU, seen)
        error = float(np.median(accuracy.centre_errors_m)) if accuracy.centre_errors_m else float("nan")
        size = float(np.median(accuracy.size_errors)) if accuracy.size_errors else float("nan")
        report.update(
            map_precision=accuracy.precision,
            map_recall=accuracy.recall,
            map_centre_error_m_median=error,
            map_size_error_median=size,
        )
        print(
            f"the map against the world's boxes annotated in >= {args.min_support} frames (3D IoU >= {IOU}):"
        )
        print(
            f"  {accuracy.true} of {accuracy.objects} map objects right (precision {accuracy.precision:.2f}),"
        )
        print(f"  {accuracy.true} of {accuracy.world} world objects found (recall {accuracy.recall:.2f}),")
        print(f"  median centre error of the right ones {error:.3f} m, size error {size:.1%}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


def _print_report(world_map: ObjectMap, measures: MapConsistency, min_support: int) -> None:
    print(f"frames mapped: {world_map.frames_mapped}; skipped: {dict(world_map.frames_skipped) or 'none'}")
    print(f"objects supported by >= {min_support} frames: {len(measures.objects)}")
    header = ("id", "class", "support", "expected", "re-det.", "centre m", "size", "yaw")
    print("{:>4} {:<12} {:>7} {:>8} {:>7} {:>8} {:>6} {:>5}".format(*header))
    for o in measures.objects:
        print(
            f"{o.id:>4} {o.cls:<12} {o.support:>7} {o.expected:>8} {o.redetection:>7.2f} "
            f"{o.centre_jitter_m:>8.3f} {o.size_jitter:>6.1%} {o.yaw_jitter_deg:>5.1f}"
        )
    print(f"median re-detection {measures.median('redetection'):.2f}; median jitter: centre")
    print(
        f"  {measures.median('centre_jitter_m'):.3f} m, size {measures.median('size_jitter'):.1%}, "
        f"yaw {measures.median('yaw_jitter_deg'):.1f} deg"
    )
    rate = measures.spurious_rate
    print(f"spurious: {measures.spurious} of {measures.detections} mapped detections ({rate:.1%})")


def _truth(frames: Path) -> dict | None:
    """FRAMES' ground truth in the evaluator's form, or None where it has none (or is no frame folder)."""
    try:
        return load_truth(frames)[0]
    except (ValueError, OSError):
        return None


if __name__ == "__main__":
    raise SystemExit(main())
