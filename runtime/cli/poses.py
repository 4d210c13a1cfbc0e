"""a3d-poses: a recording without poses (a RealSense alone) becomes a posed a3d frame folder.

    a3d-poses SOURCE --out OUT [--every N] [--voxel M]
              [--source-format KIND] [--intrinsics FX,FY,CX,CY] [--depth-scale S]

Each frame's pose is tracked (a3d.runtime.mapping.odometry: RGB-D odometry against the model fused
so far, as KinectFusion does; frames over 640 across at 640; a frame it loses is placed by its image
features matched to an earlier frame's, and its line on stderr says so) in a gravity-aligned world
(y down, the mean gravity the frames show; the first camera's heading), so that a3d-world-boxes,
a3d-labels and a3d-run --map take the recording as they take one with poses (docs/mapping.md "Poses
from the depth"). OUT (new, or empty) becomes an a3d frame folder: per tracked frame its colour (the
file's bytes) and depth, NAME.meta.json with its intrinsics, pose and the R_tilt the pose gives; and
OUT/tracking.jsonl: per frame read, whether it was tracked, the share of the model its depth
confirms and whether image features placed it ("relocalised"). A frame that is not tracked, or
cannot be read, is named on stderr in one line and not written; exit 1 if any was, 2 for an unusable
input before any frame. OUT appears whole, at the end. SOURCE is read twice (poses, then the frames
written): a recording, not a live camera.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.cli.labels import add_source_args, open_posed_source, write_posed_frame
from a3d.runtime.errors import InputError
from a3d.runtime.frontend.gravity import STATUS_OK, STATUS_WALLS_ONLY, estimate_gravity
from a3d.runtime.frontend.working_size import working_frame
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.mapping.odometry import DepthTracker, TrackerConfig, check_opencv, gravity_alignment
from a3d.runtime.pipeline import frame_problem
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.folder import TRACKING_FILE
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.pose import make_pose

PROG = "a3d-poses"
GRAVITY_EVERY = 5  # every 5th tracked frame's depth gives a gravity estimate for the world's down


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("source", type=Path, help="a recording: a frame folder, a TUM sequence, a bag, ...")
    p.add_argument("--out", type=Path, required=True, help="output frame folder (new, or empty)")
    p.add_argument(
        "--every", type=int, default=1, metavar="N",
        help="track and write every N-th frame (a 30 frames/s recording: 3 to 6)",
    )  # fmt: skip
    p.add_argument(
        "--voxel", type=float, default=TrackerConfig().voxel_m, metavar="M", help="the model's voxel, metres"
    )
    add_source_args(p)
    return p


@command(PROG)
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.every < 1:
        raise InputError(f"--every: expected a whole number >= 1, got {args.every}")
    if not 0.001 <= args.voxel <= 0.1:
        raise InputError(f"--voxel: expected 0.001 to 0.1 metres, got {args.voxel}")
    out = args.out
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"--out {out}: exists and is not an empty folder")
    check_opencv()
    source = open_posed_source(args)
    failures = list(source.incomplete)
    for problem in failures:
        print(f"{PROG}: {problem}", file=sys.stderr)
    loaders = list(source)[:: args.every]
    config = TrackerConfig(voxel_m=args.voxel)
    tracks = track_all(loaders, config, failures)
    if not tracks.poses:
        raise InputError(f"{args.source}: no frame could be tracked")
    turn = world_turn(tracks, args.source)
    written = write_tracked(out, loaders, tracks, turn, failures)
    print(f"{out}: {written} frames with poses, of {len(loaders)} read", file=sys.stderr)
    if failures:
        print(f"{PROG}: {len(failures)} frame(s) failed", file=sys.stderr)
    return 1 if failures else 0


def world_turn(tracks: Tracks, source: Path) -> np.ndarray:
    """The rotation (4, 4) taking the first camera's frame to a3d's world: the frames' mean
    gravity onto +y (from their walls alone when no frame shows a floor; the line says which)."""
    downs, what = (
        (tracks.downs, "depth") if tracks.downs else (tracks.wall_downs, "walls alone (no floor seen)")
    )
    if not downs:
        raise InputError(f"{source}: no tracked frame's depth shows which way is down (no floor, no walls)")
    alignment = gravity_alignment([tracks.poses[i] for i in downs], list(downs.values()))
    print(
        f"{PROG}: gravity from {alignment.frames} frames' {what}, median {alignment.spread_deg:.1f} degrees "
        "from their mean",
        file=sys.stderr,
    )
    return make_pose(alignment.rotation, np.zeros(3))


def write_tracked(
    out: Path, loaders: list[FrameLoader], tracks: Tracks, turn: np.ndarray, failures: list[str]
) -> int:
    """Read the tracked frames again, refine each pose against the model of all of them
    (``DepthTracker.refine``; the tracked pose where it finds no correction), and write them with
    their world poses (``turn`` after it) and tracking.jsonl into a staging folder beside ``out``
    that becomes ``out`` once whole; the frames written."""
    assert tracks.tracker is not None  # a pose was tracked
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    written = 0
    try:
        bar = tqdm(sorted(tracks.poses), desc=f"{PROG} writing", unit="frame", file=sys.stderr, disable=None)
        for i in bar:
            try:
                frame = loaders[i].load()
            except ValueError as e:  # read once already: a file changed since
                failures.append(frame_problem(loaders[i], e))
                tqdm.write(f"{PROG}: {failures[-1]}", file=sys.stderr)
                continue
            refined = tracks.tracker.refine(working_frame(frame).frame.depth, tracks.poses[i])
            tracks.records[i]["refined"] = refined is not None
            write_posed_frame(staging, frame, turn @ (tracks.poses[i] if refined is None else refined))
            written += 1
        records = "".join(json.dumps(tracks.records[i]) + "\n" for i in sorted(tracks.records))
        atomic_write_bytes(staging / TRACKING_FILE, records.encode("utf-8"))
        if out.exists():
            out.rmdir()  # empty, checked before any work
        os.replace(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return written


@dataclass
class Tracks:
    """The tracked frames' poses by loader index (the first camera's frame), their down vectors
    in their cameras where the frame gave one (``wall_downs``: from its walls alone), one
    tracking.jsonl record per frame read, by loader index, and the tracker."""

    poses: dict[int, np.ndarray] = field(default_factory=dict)
    downs: dict[int, np.ndarray] = field(default_factory=dict)
    wall_downs: dict[int, np.ndarray] = field(default_factory=dict)
    records: dict[int, dict] = field(default_factory=dict)
    tracker: DepthTracker | None = None  # holds the model of every tracked frame once done


def track_all(loaders: list[FrameLoader], config: TrackerConfig, failures: list[str]) -> Tracks:
    """Track every loader's frame in order, at the working size (frames over 640 across brought
    to it: a camera's pose does not depend on the image's size, and tracking costs its pixels);
    every GRAVITY_EVERY-th tracked frame gives its down (``add_down``)."""
    tracks = Tracks()
    bar = tqdm(loaders, desc=f"{PROG} tracking", unit="frame", file=sys.stderr, disable=None)
    for i, loader in enumerate(bar):
        try:
            frame = working_frame(loader.load()).frame  # a RealSense's 1280 x 720 tracked at 640 x 360
            if tracks.tracker is None:
                tracks.tracker = DepthTracker(frame.intrinsics, frame.depth.shape, config)
            elif frame.intrinsics != tracks.tracker.intrinsics:
                raise InputError(f"{frame.origin}: its intrinsics differ from the recording's first frame's")
            tracked = tracks.tracker.track(frame.depth, frame.color)
        except ValueError as e:  # InputError included: one line per bad frame
            failures.append(frame_problem(loader, e))
            tqdm.write(f"{PROG}: {failures[-1]}", file=sys.stderr)
            continue
        tracks.records[i] = {
            "frame": frame.name,
            "tracked": tracked.pose is not None,
            "agreement": round(tracked.agreement, 4),
            "relocalised": tracked.relocalised,
        }
        if tracked.pose is None:
            failures.append(f"{frame.origin}: not tracked ({tracked.note}); not written")
            tqdm.write(f"{PROG}: {failures[-1]}", file=sys.stderr)
            continue
        if tracked.relocalised:  # a fallback: said
            tqdm.write(f"{PROG}: {frame.origin}: {tracked.note}", file=sys.stderr)
        tracks.poses[i] = tracked.pose
        if len(tracks.poses) % GRAVITY_EVERY == 1:
            add_down(tracks, i, frame)
    return tracks


def add_down(tracks: Tracks, index: int, frame: Frame) -> None:
    """Gravity in the frame's camera: its own R_tilt's, else the depth's estimate where it finds a
    floor, else where it finds walls alone (kept apart: used only if no frame shows a floor)."""
    if frame.R_tilt is not None:
        tracks.downs[index] = np.asarray(frame.R_tilt, np.float64)[1]  # R_tilt g = [0, 1, 0]
        return
    estimate = estimate_gravity(frame.depth, frame.intrinsics)
    if estimate.status == STATUS_OK:
        tracks.downs[index] = estimate.gravity
    elif estimate.status == STATUS_WALLS_ONLY:
        tracks.wall_downs[index] = estimate.gravity


if __name__ == "__main__":
    sys.exit(main())
