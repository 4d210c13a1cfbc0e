"""a3d-labels: ground truth for every frame of a posed recording, from boxes drawn once in the world.

    a3d-labels WORLD_BOXES.json SOURCE --out OUT [--min-seen-px 50] [--margin 0.03] [--floor-gap 0.02]
               [--source-format KIND] [--intrinsics FX,FY,CX,CY] [--depth-scale S]

WORLD_BOXES.json holds each object once, as a box in a gravity-aligned world (y down;
a3d.runtime.mapping.world_boxes); SOURCE is any posed frame source (an a3d frame folder with
poses in its meta.json, a TUM sequence with groundtruth.txt, a 7-Scenes-style folder) whose poses
are in that world. OUT becomes an a3d frame folder: per posed frame its colour (the file's bytes)
and depth, NAME.meta.json with its intrinsics, the R_tilt its pose gives and the pose,
NAME.gt.json with the objects the frame sees and NAME.instances.png with their seen pixels
(a3d.runtime.mapping.labels, docs/mapping.md "Labels drawn once"); OUT/labels.jsonl says, per
frame and per object in view, its seen and expected pixels, its visibility and whether it got an
entry. A frame without a pose, or that cannot be read, is named on stderr in one line and not
written; exit 1 if any was, 2 for an unusable input before any frame.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.image_io import read_bytes
from a3d.runtime.mapping.labels import FrameLabels, LabelConfig, label_frame
from a3d.runtime.mapping.world import rtilt_from_pose
from a3d.runtime.mapping.world_boxes import WorldBoxes, read_world_boxes
from a3d.runtime.pipeline import frame_problem
from a3d.runtime.sources.folder import LABELS_FILE, write_frame
from a3d.runtime.sources.overrides import parse_depth_scale, parse_intrinsics
from a3d.runtime.sources.registry import FrameSource, SourceOptions, kinds, open_source
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.pose import rotation_deg

PROG = "a3d-labels"
GRAVITY_DISAGREES_DEG = 2.0  # a frame's own R_tilt this far from its pose's gravity: a warning


def build_parser() -> argparse.ArgumentParser:
    defaults = LabelConfig()
    p = command_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("world_boxes", type=Path, help="world_boxes.json: the objects, once, in the world")
    p.add_argument("source", type=Path, help="a posed frame source whose poses are in that world")
    p.add_argument("--out", type=Path, required=True, help="output frame folder (created)")
    p.add_argument("--min-seen-px", type=int, default=defaults.min_seen_px, help="seen pixels an entry needs")
    p.add_argument(
        "--margin", type=float, default=defaults.margin_m, help="metres the boxes grow for depth noise"
    )
    p.add_argument(
        "--floor-gap", type=float, default=defaults.floor_gap_m, help="metres the boxes' bottoms are raised"
    )
    add_source_args(p)
    return p


def add_source_args(p: argparse.ArgumentParser) -> None:
    """How SOURCE is read: its kind, and the intrinsics and depth scale that replace its own
    (a3d-labels and a3d-world-boxes read posed sources alike)."""
    p.add_argument("--source-format", choices=kinds(), help="the kind of SOURCE (default: recognised)")
    p.add_argument("--intrinsics", metavar="FX,FY,CX,CY", help="replaces the source's intrinsics")
    p.add_argument("--depth-scale", metavar="S", help="metres per depth unit, replaces the source's")


def open_posed_source(args: argparse.Namespace) -> FrameSource:
    """SOURCE as ``add_source_args``' flags say, without proposals (the frames are only read)."""
    options = SourceOptions(
        intrinsics=None if args.intrinsics is None else parse_intrinsics(args.intrinsics),
        depth_scale=None if args.depth_scale is None else parse_depth_scale(args.depth_scale),
        with_proposals=False,
    )
    return open_source(args.source, options, args.source_format)


@command(PROG)
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.min_seen_px < 1 or args.margin < 0 or args.floor_gap < 0:
        parser.error("--min-seen-px must be >= 1, --margin and --floor-gap >= 0")
    if args.out.resolve() == args.source.resolve():
        parser.error("--out must not be SOURCE (its frames would be overwritten)")
    config = LabelConfig(args.min_seen_px, args.margin, args.floor_gap)
    world = read_world_boxes(args.world_boxes)
    source = open_posed_source(args)
    failures = list(source.incomplete)
    for problem in failures:
        print(f"{PROG}: {problem}", file=sys.stderr)
    records, objects = [], 0
    for loader in tqdm(list(source), desc=PROG, unit="frame", file=sys.stderr, disable=None):
        try:
            frame = loader.load()
            if frame.pose is None:
                raise InputError(f"{frame.origin}: {frame.pose_note or 'no pose'}; not labelled")
            labels = write_labelled_frame(args.out, frame, world, config)
        except ValueError as e:  # InputError included: one line per bad frame
            failures.append(frame_problem(loader, e))
            tqdm.write(f"{PROG}: {failures[-1]}", file=sys.stderr)
            continue
        records.append(labels_record(frame.name, world, labels))
        objects += len(labels.truth)
    atomic_write_bytes(args.out / LABELS_FILE, "".join(json.dumps(r) + "\n" for r in records).encode("utf-8"))
    print(f"{args.out}: {len(records)} frames labelled, {objects} objects seen", file=sys.stderr)
    if failures:
        print(f"{PROG}: {len(failures)} frame(s) failed", file=sys.stderr)
    return 1 if failures else 0


def write_labelled_frame(out: Path, frame: Frame, world: WorldBoxes, config: LabelConfig) -> FrameLabels:
    """Label one posed frame and write it into ``out`` with its ground truth (module docstring)."""
    assert frame.pose is not None
    R_tilt = rtilt_from_pose(frame.pose)
    if frame.R_tilt is not None:
        angle = rotation_deg(frame.R_tilt @ R_tilt.T)
        if angle > GRAVITY_DISAGREES_DEG:
            tqdm.write(
                f"{PROG}: warning: {frame.origin}: its R_tilt is {angle:.1f} degrees from its pose's gravity "
                "(is the poses' world gravity-aligned, y down?); labelled with the pose's",
                file=sys.stderr,
            )
    labels = label_frame(world, frame.pose, R_tilt, frame.depth, frame.intrinsics, config)
    write_posed_frame(out, frame, frame.pose, labels)
    return labels


def write_posed_frame(out: Path, frame: Frame, pose: np.ndarray, labels: FrameLabels | None = None) -> None:
    """Write ``frame`` into the frame folder ``out`` as read (its colour file's bytes, its depth in
    its own format), with its intrinsics, ``pose``, the R_tilt the pose gives and, given, its labels."""
    color = read_bytes(Path(frame.color_file)) if frame.color_file else frame.color
    npy = frame.depth_file is not None and frame.depth_file.lower().endswith(".npy")
    write_frame(
        out,
        frame.name,
        color,
        frame.depth,
        R_tilt=rtilt_from_pose(pose),
        intrinsics_override=frame.intrinsics,
        gt=None if labels is None else labels.truth,
        instances=None if labels is None else labels.instances,
        depth_format="npy" if npy else "png",
        pose=pose,
    )


def labels_record(name: str, world: WorldBoxes, labels: FrameLabels) -> dict:
    """The labels.jsonl line of a frame: every world object whose box is in view."""
    seen = set(labels.ids.tolist())
    objects = [
        {
            "id": int(world.ids[i]),
            "class": world.classes[i],
            "seen_px": int(labels.seen_px[i]),
            "expected_px": round(float(labels.expected_px[i]), 1),
            "visibility": round(float(labels.visibility[i]), 4),
            "labelled": int(world.ids[i]) in seen,
        }
        for i in np.flatnonzero(labels.expected_px > 0)
    ]
    return {"frame": name, "objects": objects}


if __name__ == "__main__":
    sys.exit(main())
