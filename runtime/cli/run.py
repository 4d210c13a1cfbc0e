"""a3d-run: detect the objects in every frame of a source; one JSON line per frame, live rerun view.

    a3d-run FOLDER [--model model.onnx] [--output detections.jsonl] [--threads 2]
            [--detector NAME|FILE|none] [--detector-names FILE] [--class-map FILE] [--classifier NAME|FILE]
            [--proposals auto|compute|precomputed] [--max-proposals N] [--front-end model|live]
            [--working-side PX]
            [--score-threshold S] [--raw-scores]
            [--resume] [--overlap [auto|on|off]] [--headless] [--connect] [--url URL] [--serve]
            [--save FILE.rrd] [--stdout]
            [--intrinsics FX,FY,CX,CY | fr1 | fr2 | fr3] [--depth-scale S] [--resize-depth] [--shard K/N]
            [--color-topic TOPIC] [--depth-topic TOPIC] [--pose-topic TOPIC] [--max-frames N]
            [--map [MAP.json]]
            [--ray [ADDRESS] [--ray-workers N]]

SOURCE is a frame source (a3d.runtime.sources.registry: an a3d frame folder, README "Frame
format", and the other kinds registered there; --source-format forces one); for a folder the
model defaults to FOLDER/model.onnx. The
model is loaded and checked before any frame is read. Each frame goes through
a3d.runtime.pipeline and its line (README "Detections format") is appended to the output as one
write straight to the file (no buffer in the process), so a killed run leaves only complete lines
(at most a partial last one, which ``--resume`` cuts off before it skips the frames already
written); the file is fsynced after the first line, then at most once a second and at the end, so
a power cut loses at most the last second's lines rather than every frame waiting on the disk. Without
``--resume`` the output starts empty. ``--output -`` writes the lines to stdout; the progress bar
and all messages go to stderr.

The rerun flags are the SDK's standard ones: with none the viewer is started (on 127.0.0.1, found
next to this Python when not on PATH; a3d.runtime.viewer.launch), ``--serve`` serves the web
viewer and prints its URL, ``--save`` writes an .rrd, ``--headless`` alone logs nothing. The run
ends with a summary (a3d.runtime.cli.summary); progress is a bar on a terminal, else a line every
few seconds (a3d.runtime.cli.progress). Live sources and ``--realtime`` work on the newest frame
only (a3d.runtime.sources.newest); docs/live.md. Frames are logged as they are processed (colour, depth,
point cloud, detections and, where the frame has it, ground truth).

``--map [MAP.json]`` fuses the detections of every frame into one box per object in the world
(a3d.runtime.mapping.object_map, docs/mapping.md), written atomically at the end of the run (also
an interrupted one); on a source without camera poses (a RealSense alone) each frame's pose is
tracked from its depth as it is read (a3d.runtime.mapping.tracked_poses), and the run says so.

``--ray [ADDRESS]`` (the ``ray`` extra) spreads the frames over the actors of a Ray cluster (a new
local one without ADDRESS), each running one model on ``--threads`` threads; the output is the same
file, written when the run ends (a3d.runtime.scale, docs/running.md "Scale-out on Ray").

A bad frame never stops the run: it is named on stderr as ``a3d-run: PATH: problem`` and the rest
are processed. Exit codes: 0 every frame done, 1 some frames failed, 2 usage error (bad flags, no
or unusable model, missing folder, unreadable output) before any frame is processed, 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from a3d.runtime.classifier2d import CLASSIFIERS, Classifier2D
from a3d.runtime.cli.common import EXIT_USAGE, command
from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.progress import make_progress
from a3d.runtime.cli.summary import RunSummary
from a3d.runtime.detector2d import DETECTORS, Detector2D
from a3d.runtime.errors import InputError, ModelError
from a3d.runtime.frontend.working_size import WORKING_SIDE
from a3d.runtime.io.detections_io import format_line
from a3d.runtime.mapping.object_map import ObjectMap
from a3d.runtime.mapping.tracked_poses import FramePoses, with_tracked_poses
from a3d.runtime.mapping.world import WORLD_AXES, down_of_up_axis
from a3d.runtime.models import DEFAULT_MODEL as DEFAULT_NAME
from a3d.runtime.models import MODELS, NO_DETECTOR, model_path, pipeline_detector
from a3d.runtime.models.card import detector_card, model_card
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import (
    FRONT_ENDS,
    PROPOSAL_SOURCES,
    FrameOutcome,
    NetworkRunner,
    PipelineConfig,
    detect_frames,
    detect_frames_auto,
)
from a3d.runtime.postprocess.score_calibration import SHOW_THRESHOLD
from a3d.runtime.scale import plan, ray_run
from a3d.runtime.selection import completed_frames, frames_to_do
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.folder import MODEL_FILE
from a3d.runtime.sources.newest import NewestFrames
from a3d.runtime.sources.overrides import parse_depth_scale, parse_intrinsics, with_overrides
from a3d.runtime.sources.registry import FrameSource, SourceOptions, kinds, open_source, recognised
from a3d.runtime.viewer import launch as viewer_launch
from a3d.runtime.viewer import options as viewer

if TYPE_CHECKING:
    import rerun as rr

PROG = "a3d-run"
OVERLAP_MODES = ("auto", "on", "off")
SYNC_SECONDS = 1.0  # the detections file is fsynced at most this often (also after line 1 and at the end)
OVERLAP_NOTE = (
    "the front end is the longer part: next frames prepared in the background, the network on {n} - 1 threads"
)
LIVE_NOTE = (
    "live source: using the live front end (faster proposals, docs/live.md); "
    "--front-end model keeps the model's own"
)
DEFAULT_MODEL = MODEL_FILE
DEFAULT_OUTPUT = "detections.jsonl"
DEFAULT_MAP = "map.json"
TRACKING_NOTE = (
    "no camera poses: --map tracks them from the depth as the frames come (a3d-poses' tracker, without "
    'its refinement over the whole recording: docs/mapping.md "A source without poses")'
)
VIEW_MIN_SCORE = SHOW_THRESHOLD  # calibrated scores: a detection there is as likely right as wrong

load_model = DetectorModel.load  # the model loader (tests substitute a fake model here)


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("source", type=Path, help="frame source: an a3d frame folder or another registered kind")
    p.add_argument("--source-format", choices=kinds(), help="the kind of SOURCE (default: recognised)")
    p.add_argument("--model", help=f"a bundled model by name ({', '.join(MODELS)}) or a model file (default: "
                   f"FOLDER/{DEFAULT_MODEL} where it exists, else {DEFAULT_NAME})")  # fmt: skip
    p.add_argument("--model-info", action=_ModelInfo, metavar="NAME|FILE",
                   help="print a model's card (from its metadata) and exit")  # fmt: skip
    p.add_argument("--detector", metavar="NAME|FILE",
                   help=f"a 2D detector ({', '.join(DETECTORS)}, or an ONNX file of YOLOX's, NanoDet's or a "
                   f"boxes/scores/labels layout) whose boxes join the RoIs; '{NO_DETECTOR}': none (default: "
                   "the bundled pipeline's, e.g. --model real's)")  # fmt: skip
    p.add_argument("--detector-names", type=Path, metavar="FILE",
                   help="--detector's class names, a line each (default: its metadata, or COCO)")  # fmt: skip
    p.add_argument("--class-map", type=Path, metavar="FILE",
                   help='JSON {"detector class": "a3d class" | [a3d classes]} (default: COCO)')  # fmt: skip
    p.add_argument("--classifier", metavar="NAME|FILE",
                   help=f"an image classifier ({', '.join(CLASSIFIERS)}, or an ONNX file) rescoring the "
                   "best own detections of classes the 2D detector lacks (default: none)")  # fmt: skip
    p.add_argument("--color-topic", metavar="TOPIC", help="bag: the colour topic (default: the only one)")
    p.add_argument("--depth-topic", metavar="TOPIC", help="bag: the depth topic (default: the only one)")
    p.add_argument("--pose-topic", metavar="TOPIC",
                   help="bag: the camera's PoseStamped/Odometry topic (default: the only one)")  # fmt: skip
    p.add_argument("--output", default=DEFAULT_OUTPUT, help="JSON lines file, '-': stdout")
    p.add_argument("--threads", type=int, default=2, help="CPU threads, OpenCV and ONNX Runtime")
    p.add_argument(
        "--proposals",
        choices=PROPOSAL_SOURCES,
        default="auto",
        help="auto: NAME.proposals.npz where present, else computed; compute: always computed; "
        "precomputed: NAME.proposals.npz required",
    )
    p.add_argument("--max-proposals", type=int, metavar="N", help="proposals per frame (default: model)")
    p.add_argument(
        "--working-side",
        type=int,
        default=WORKING_SIDE,
        metavar="PX",
        help="a frame whose longer side is over PX pixels is brought down to it first, as the networks "
        "were trained (2D boxes are reported in the frame's own pixels); 0: every frame as it comes "
        f"(default: {WORKING_SIDE})",
    )
    p.add_argument(
        "--front-end",
        choices=FRONT_ENDS,
        help="proposal settings: model (the model's own) or live (about 4x faster, a few points of "
        "recall: docs/live.md); default: live for cameras and --realtime, else model",
    )
    p.add_argument(
        "--score-threshold",
        type=float,
        metavar="S",
        help="write only detections scoring >= S (default: the model's, 0 for the bundled one: every "
        "per-class top-k detection, which a3d-eval needs to trace the whole precision-recall curve)",
    )
    p.add_argument(
        "--raw-scores",
        action="store_true",
        help="write the network's softmax scores, without the model's score calibration (a model "
        'exported with --score-calibration: docs/training.md "Exporting a model")',
    )
    p.add_argument("--resume", action="store_true", help="skip the frames the output already has")
    p.add_argument("--max-frames", type=int, metavar="N", help="stop after the first N frames of the source")
    p.add_argument(
        "--view-min-score",
        type=float,
        default=VIEW_MIN_SCORE,
        metavar="S",
        help="rerun view and summary: detections scoring >= S (all are written to the output; default: "
        "%(default)s: with the model's calibrated scores a detection there is as likely right as wrong; "
        "docs/live.md)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="play a recorded source at its recorded rate (frame time stamps) and, as with a live "
        "camera, work on the newest frame only, dropping the stale ones",
    )
    p.add_argument(
        "--overlap",
        choices=OVERLAP_MODES,
        nargs="?",
        const="auto",
        default="auto",
        help="prepare the next frame on a background thread during the network call, the network then "
        "on THREADS - 1 threads: on, off, or auto (also a bare --overlap): a frame after the first is "
        "timed sequentially and the rest overlap only where that is predicted faster",
    )
    p.add_argument(
        "--intrinsics",
        metavar="FX,FY,CX,CY",
        help="camera intrinsics in pixels for every frame, or a preset (fr1|fr2|fr3: TUM RGB-D); "
        "replaces what the source says",
    )
    p.add_argument(
        "--depth-scale", metavar="S", help="metres per depth unit (0.001: mm), replaces the source's"
    )
    p.add_argument("--resize-depth", action="store_true", help="resize depth of another size to the colour's")
    p.add_argument("--shard", metavar="K/N", help="only every N-th frame from the K-th (K = 0..N-1)")
    p.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDRESS",
        help="run the frames on the actors of a Ray cluster (ADDRESS; a bare --ray, after SOURCE: a new "
        "local one), each with its own model on --threads threads; needs 'a3d[ray]' and --headless",
    )
    p.add_argument(
        "--ray-workers",
        type=int,
        metavar="N",
        help="--ray: how many actors (default: the cluster's CPUs / --threads)",
    )
    p.add_argument(
        "--world-up",
        choices=WORLD_AXES,
        help="posed sources: the poses' world is gravity-aligned with this axis up, so gravity comes from "
        'each frame\'s pose instead of its depth (docs/sources.md "Camera poses")',
    )
    p.add_argument(
        "--map",
        nargs="?",
        const=Path(DEFAULT_MAP),
        type=Path,
        metavar="MAP.json",
        help="fuse the detections into a world-frame object map (bare --map: "
        f"{DEFAULT_MAP}); a source without poses gets them tracked from its depth",
    )
    viewer.add_viewer_args(p)
    return p


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    """Parsed and checked flags (argparse exits with status 2 and its usage line on a usage error);
    a missing source or model is InputError, one line without the usage."""
    parser = build_parser()
    args = parser.parse_args(argv)
    _check_ray(parser, args)
    if args.threads < 1:
        parser.error("--threads must be at least 1")
    if args.max_frames is not None and args.max_frames < 1:
        parser.error("--max-frames must be at least 1")
    if args.max_proposals is not None and args.max_proposals < 1:
        parser.error("--max-proposals must be at least 1")
    if args.working_side < 0:
        parser.error("--working-side must be 0 (as the frames come) or a number of pixels")
    if args.score_threshold is not None and not 0.0 <= args.score_threshold <= 1.0:
        parser.error("--score-threshold must be in [0, 1]")
    if args.output == "-" and (args.resume or args.stdout):
        parser.error("--output - cannot be combined with --resume or --stdout")
    if not args.source.exists() and ":" not in str(args.source) and not recognised(args.source):
        raise InputError(f"{args.source}: no such file or folder")
    args.shard = _shard(parser, args.shard)
    if args.map is not None and (args.resume or args.shard != (0, 1)):
        parser.error("--map needs every frame in order: it excludes --resume and --shard")
    beside = args.source / DEFAULT_MODEL
    named = args.model if args.model is not None or not beside.is_file() else beside
    args.model_name = named  # its pipeline's detector is chosen once the file (which may name one) is read
    args.model = model_path(named)
    return args


class _ModelInfo(argparse.Action):
    """--model-info NAME|FILE: the model's card, then exit (as --version does, without a source)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: object, value: object, *_: object) -> None:
        path = model_path(str(value))
        try:
            metadata = DetectorModel.load(path, threads=1).metadata
        except ModelError as e:
            parser.exit(EXIT_USAGE, f"{PROG}: error: {e}\n")
        detector = pipeline_detector(str(value), named=metadata.detector)
        extra = [] if detector is None else detector_card(os.fspath(detector))
        print("\n".join([*model_card(path, metadata), *extra]))
        parser.exit(0)


def _check_ray(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """--ray: Ray installed (one line naming the extra, before anything else) and no flag that needs
    the frames in one process (argparse's usage error naming the first)."""
    if args.ray is None:
        if args.ray_workers is not None:
            parser.error("--ray-workers needs --ray")
        return
    ray_run.NEEDS.check()
    if args.ray_workers is not None and args.ray_workers < 1:
        parser.error("--ray-workers must be at least 1")
    excluded = {
        "--output -": args.output == "-",
        "--realtime": args.realtime,
        "--map": args.map is not None,
        f"--overlap {args.overlap}": args.overlap != "auto",
    }
    for flag, given in excluded.items():
        if given:
            parser.error(f"--ray writes a detections file, each worker doing its frames in turn: not {flag}")
    if viewer.viewer_requested(args):
        parser.error("--ray writes the detections only, without a view: add --headless")


def _shard(parser: argparse.ArgumentParser, text: str | None) -> tuple[int, int]:
    """--shard K/N as (K, N); (0, 1) without it."""
    if text is None:
        return 0, 1
    k, _, n = text.partition("/")
    if not (k.isdigit() and n.isdigit() and 0 <= int(k) < int(n)):
        parser.error(f"--shard: expected K/N with 0 <= K < N, got {text!r}")
    return int(k), int(n)


@dataclass(frozen=True)
class _Job:
    """What a run needs, all checked before the first frame: the frames, the model, the settings."""

    source: FrameSource
    done: set[str]  # the frames --resume found in the output
    model: DetectorModel
    config: PipelineConfig
    poses: FramePoses | None = None  # --map on a source without poses: tracked from the depth


def _job(args: argparse.Namespace) -> _Job:
    """Open the source, load the model and read the output to resume (InputError / ModelError)."""
    topics = {"color_topic": args.color_topic, "depth_topic": args.depth_topic, "pose_topic": args.pose_topic}
    options = SourceOptions(
        intrinsics=None if args.intrinsics is None else parse_intrinsics(args.intrinsics),
        depth_scale=None if args.depth_scale is None else parse_depth_scale(args.depth_scale),
        resize_depth=args.resize_depth,
        with_proposals=args.proposals != "compute",
        with_truth=viewer.viewer_requested(args),
        extra={key: value for key, value in topics.items() if value is not None},
    )
    source = open_source(args.source, options, args.source_format)
    if args.world_up is not None:
        if not getattr(source, "has_poses", False):
            raise InputError(f"{args.source}: --world-up needs camera poses, and this source has none")
        source = with_overrides(source, None, None, world_down=down_of_up_axis(args.world_up))
    poses = None
    if args.map is not None and not getattr(source, "has_poses", False):
        poses = FramePoses()  # InputError without OpenCV's 3D module
        print(f"{PROG}: {args.source}: {TRACKING_NOTE}", file=sys.stderr)
    # With --overlap on one thread prepares frames, so the network gets one fewer (no oversubscription).
    model = load_model(args.model, threads=max(1, args.threads - 1) if args.overlap == "on" else args.threads)
    front_end = args.front_end or ("live" if _is_live(args, source) else "model")
    if args.front_end is None and front_end == "live":
        print(f"{PROG}: {LIVE_NOTE}", file=sys.stderr)
    config = PipelineConfig.from_metadata(
        model.metadata,
        proposal_source=args.proposals,
        max_proposals=args.max_proposals,
        min_score=args.score_threshold,
        front_end=front_end,
        raw_scores=args.raw_scores,
    )
    config = replace(config, working_side=args.working_side)
    detector = pipeline_detector(args.model_name, args.detector, model.metadata.detector)
    if detector is None and (args.detector_names is not None or args.class_map is not None):
        raise InputError("--detector-names and --class-map need a 2D detector (--detector or --model real)")
    if detector is not None:
        boxes = Detector2D.load(detector, names=args.detector_names, class_map=args.class_map)
        config = replace(config, detector=boxes)
    if args.classifier is not None:
        config = replace(config, classifier=Classifier2D.load(args.classifier, threads=args.threads))
    done = completed_frames(Path(args.output)) if args.resume else set()
    return _Job(source, done, model, config, poses)


@dataclass(frozen=True)
class FrameReport:
    """What a run did with one frame, handed to ``main``'s ``on_frame`` once the frame is written and
    logged: for callers that time a3d-run's own loop (bench/edge_speed.py) without patching it.
    ``output_seconds``: formatting + writing the line; ``log_seconds``: the synchronous rerun logging."""

    outcome: FrameOutcome
    output_seconds: float
    log_seconds: float


@command(PROG)
def main(argv: list[str] | None = None, on_frame: Callable[[FrameReport], None] | None = None) -> int:
    args = _arguments(argv)
    if args.ray is not None:
        return _ray_main(args)
    viewer.check_installed(args)  # no rerun: one line naming 'a3d[view]', before a view mode is suggested
    starts_viewer = viewer_launch.launches_viewer(args)
    if starts_viewer:
        viewer_launch.check_can_launch(args)  # no display, no viewer: one line before loading anything
    elif args.connect:
        viewer_launch.check_connect_target(args)
    job = _job(args)  # InputError / ModelError: exit 2 before any frame (command)
    launched = viewer_launch.launch(args) if starts_viewer else None
    recording = _open_recording(args, launched)
    view = viewer.ViewOptions(min_score=args.view_min_score)
    output = _open_output(args.output, append=args.resume)
    if launched is not None and launched.web_url is not None:
        print(f"{PROG}: web viewer: open {launched.web_url}", file=sys.stderr, flush=True)
    failures = list(job.source.incomplete)
    for problem in failures:
        print(f"{PROG}: {problem}", file=sys.stderr)
    written = 0
    overlapping = False
    index: dict[str, int] = {}  # frame name -> its position in the source (the rerun timeline)
    live = NewestFrames(job.source, realtime=args.realtime) if _is_live(args, job.source) else None
    todo = frames_to_do(job.source if live is None else live, job.done, index, args.shard, args.max_frames)
    if job.poses is not None:
        todo = with_tracked_poses(todo, job.poses)
    total = None
    if live is None and hasattr(job.source, "__len__"):
        k, n = args.shard
        count = len(job.source) if args.max_frames is None else min(len(job.source), args.max_frames)
        total = max(0, len(range(k, count, n)) - len(job.done))
    bar = make_progress(PROG, total)
    summary = RunSummary(args.view_min_score, calibrated=job.config.score_calibration is not None)
    world_map = None if args.map is None else ObjectMap()
    try:
        with _threads(1 if args.overlap == "on" else args.threads), _warnings_to_stderr():
            for outcome in _frames(todo, job, args):
                problem = outcome.problem
                start = written_at = logged_at = time.perf_counter()
                if outcome.detections is not None:
                    output.write(format_line(outcome.detections))
                    written += 1
                    written_at = time.perf_counter()
                    summary.add(outcome.detections)
                    problem = _log(recording, index[outcome.name], outcome, view)
                    problem = (
                        problem
                        or _update_map(world_map, outcome)
                        or _log_map(recording, index, world_map, outcome)
                    )
                    logged_at = time.perf_counter()
                else:
                    summary.fail()
                if on_frame is not None:
                    on_frame(FrameReport(outcome, written_at - start, logged_at - written_at))
                if outcome.overlapped and not overlapping and args.overlap == "auto":
                    overlapping = True
                    bar.write(f"{PROG}: --overlap auto: {OVERLAP_NOTE.format(n=args.threads)}")
                if problem:
                    failures.append(problem)
                    bar.write(f"{PROG}: {problem}")
                bar.update(failed=outcome.detections is None)
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted after {written} frames; --resume continues", file=sys.stderr)
        if launched is not None and launched.web_url is not None:
            launched.stop()
        return 130
    except OSError as e:
        print(f"{PROG}: error: {args.output}: cannot write ({e.strerror or e}); stopped", file=sys.stderr)
        return 1
    finally:
        todo.close()
        bar.close()
        output.close()
        if recording is not None:
            _flush(recording)
        if world_map is not None:
            _write_map(world_map, args.map)
    resumed = f", {len(job.done)} already there" if args.resume else ""
    where = "stdout" if args.output == "-" else args.output
    summary.dropped = None if live is None else live.dropped
    for line in summary.lines(_outputs(args, where, launched)):
        print(f"{PROG}: summary: {line}", file=sys.stderr)
    print(f"{PROG}: {written} frames written to {where}{resumed}, {len(failures)} failed", file=sys.stderr)
    if recording is not None:
        viewer.load_view().close_recording(args, recording, own_viewer=launched is not None)
    if launched is not None and launched.web_url is not None:
        _serve_until_interrupted(launched)
    return 1 if failures else 0


def _ray_main(args: argparse.Namespace) -> int:
    """--ray: the frames on Ray actors (a3d.runtime.scale), with a3d-run's file, problem lines,
    progress and exit codes; usage errors (a bag or camera, no model) before Ray starts."""
    plan.check_independent(args.source, args.source_format)  # before a camera is opened
    job = _job(args)
    ray_job = ray_run.RayJob(job.source, args.model, job.config, args.threads)
    runner = ray_run.RayRunner(
        ray_job, args.output, resume=args.resume, done=job.done, shard=args.shard, limit=args.max_frames
    )
    bar = make_progress(PROG, len(runner.listing))
    try:
        result = runner.run(
            workers=args.ray_workers,
            address=args.ray or None,
            on_problem=lambda problem: bar.write(f"{PROG}: {problem}"),
            on_frame=lambda failed: bar.update(failed=failed),
        )
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted; the finished blocks are kept: --resume continues", file=sys.stderr)
        return 130
    except ray_run.RayFailed as e:
        print(f"{PROG}: error: {e}; the finished blocks are kept: --resume continues", file=sys.stderr)
        return 1
    finally:
        bar.close()
    resumed = f", {result.already} already there" if args.resume else ""
    print(
        f"{PROG}: {result.written} frames written to {args.output}{resumed}, {len(result.failed)} failed",
        file=sys.stderr,
    )
    return 1 if result.failed else 0


def _update_map(world_map: ObjectMap | None, outcome: FrameOutcome) -> str:
    """Add a processed frame to the map (with its camera, so the map knows what it should have
    seen); the problem, if that failed (the line is written either way), else ""."""
    if world_map is None:
        return ""
    assert outcome.prepared is not None and outcome.detections is not None
    frame = outcome.prepared.frame
    try:
        world_map.update(outcome.detections, intrinsics=frame.intrinsics, depth=frame.depth)
    except Exception as e:  # the line is written; the map must not stop the run
        return f"{frame.origin}: map: cannot add the frame ({type(e).__name__}: {e})"
    return ""


def _log_map(
    recording: rr.RecordingStream | None,
    index: dict[str, int],
    world_map: ObjectMap | None,
    outcome: FrameOutcome,
) -> str:
    """Log the map after a mapped frame (its camera, the trajectory, the objects); the problem, if
    logging failed, else ""."""
    if recording is None or world_map is None or world_map.camera is None:
        return ""
    assert outcome.prepared is not None
    frame = outcome.prepared.frame
    objects = world_map.objects
    try:
        viewer.load_view().log_map(
            recording,
            index[outcome.name],
            camera_pose=world_map.camera,
            K=frame.intrinsics,
            image_size=frame.image_size,
            trajectory=np.array(world_map.trajectory),
            class_ids=np.array([o.class_id for o in objects], np.int64),
            boxes=np.array([o.box for o in objects]).reshape(-1, 7),
            labels=[f"{o.cls} #{o.id} ({o.support})" for o in objects],
        )
    except Exception as e:  # the line is written; a viewer problem must not stop the run
        return f"{frame.origin}: rerun: cannot log the map ({type(e).__name__}: {e})"
    return ""


def _write_map(world_map: ObjectMap, path: Path) -> None:
    """Write the map (atomically) and say in one line what it holds and which frames it left out."""
    try:
        world_map.write(path)
    except OSError as e:
        print(f"{PROG}: error: {path}: cannot write the map ({e.strerror or e})", file=sys.stderr)
        return
    skipped = ", ".join(f"{n} {why}" for why, n in world_map.frames_skipped.items())
    n, confirmed, support = len(world_map.objects), len(world_map.confirmed()), world_map.config.min_support
    frames = world_map.frames_mapped
    line = f"{n} objects ({confirmed} seen in >= {support} frames) from {frames} frames -> {path}"
    print(f"{PROG}: map: {line}" + (f"; frames not mapped: {skipped}" if skipped else ""), file=sys.stderr)


def _flush(recording: rr.RecordingStream) -> None:
    """Send what the viewer has not received yet; a viewer gone mid-run is one line, not a traceback
    (the detections are written either way)."""
    try:
        recording.flush()
    except RuntimeError as e:
        print(f"{PROG}: warning: rerun: the viewer did not receive everything ({e})", file=sys.stderr)


def _is_live(args: argparse.Namespace, source: FrameSource) -> bool:
    """Live sources (a camera: ``source.live``) and --realtime runs work on the newest frame only."""
    return bool(args.realtime or getattr(source, "live", False))


def _outputs(args: argparse.Namespace, where: str, launched: viewer_launch.Launched | None) -> list[str]:
    """Where the run's outputs went, for the summary."""
    outputs = [f"detections -> {where}"]
    if args.save:
        outputs.append(f"recording -> {args.save}")
    if args.connect:
        outputs.append(f"viewer -> {args.url or 'the default viewer address'}")
    if launched is not None:
        outputs.append(f"viewer -> {launched.web_url or launched.grpc_url}")
    return outputs


def _serve_until_interrupted(launched: viewer_launch.Launched) -> None:
    """--serve: the web viewer keeps the recording until Ctrl-C (or SIGTERM), then is stopped."""
    print(f"{PROG}: serving the recording at {launched.web_url}; Ctrl-C to stop", file=sys.stderr, flush=True)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a plain `kill` stops the server too
    try:
        while launched.process is not None and launched.process.poll() is None:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        launched.stop()


def _frames(todo: Iterator[FrameLoader], job: _Job, args: argparse.Namespace) -> Iterator[FrameOutcome]:
    """The pipeline's outcomes in the --overlap mode asked for (auto: pipeline.detect_frames_auto)."""
    if args.overlap != "auto":
        return detect_frames(todo, job.model, job.config, overlap=args.overlap == "on")

    def narrow(threads: int) -> NetworkRunner:
        cv2.setNumThreads(1)  # the background thread's OpenCV leaves the other cores to the network
        return load_model(args.model, threads=threads)

    return detect_frames_auto(todo, job.model, job.config, threads=args.threads, narrow=narrow)


# ----------------------------------------------------------------------------- output file


class _LineSink:
    """Appends lines to a file (one write per line; fsynced after the first line, then at most
    every SYNC_SECONDS and on close) or to stdout (flushed per line)."""

    def __init__(self, fd: int | None) -> None:
        self.fd = fd
        self.synced = -math.inf  # when the file was last fsynced (time.monotonic)

    def write(self, line: str) -> None:
        data = (line + "\n").encode("utf-8")
        if self.fd is None:
            sys.stdout.buffer.write(data)
            sys.stdout.buffer.flush()
            return
        view = memoryview(data)
        while view:  # a regular file takes the whole line in one call; the loop only guards EINTR-like cases
            view = view[os.write(self.fd, view) :]
        if time.monotonic() - self.synced >= SYNC_SECONDS:
            os.fsync(self.fd)
            self.synced = time.monotonic()

    def close(self) -> None:
        if self.fd is not None:
            os.fsync(self.fd)
            os.close(self.fd)


def _open_output(target: str, append: bool) -> _LineSink:
    """stdout for "-", else the file, emptied first unless ``append`` (InputError if it cannot be)."""
    if target == "-":
        return _LineSink(None)
    path = Path(target)
    flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | (0 if append else os.O_TRUNC)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return _LineSink(os.open(path, flags, 0o666))
    except OSError as e:
        raise InputError(f"{path}: cannot write ({e.strerror or e})") from None


# ----------------------------------------------------------------------------- viewer, environment


def _open_recording(
    args: argparse.Namespace, launched: viewer_launch.Launched | None
) -> rr.RecordingStream | None:
    """The rerun recording the flags ask for (to the viewer a3d-run started, if it started one),
    with the static entities logged; None for none."""
    if not viewer.viewer_requested(args):
        return None
    view = viewer.load_view()  # rerun is imported here, only when a view or recording is asked for
    try:
        recording = view.open_recording(args, None if launched is None else launched.grpc_url)
        view.log_static(recording)
    except (OSError, RuntimeError, ValueError) as e:
        raise InputError(f"rerun: cannot open the recording ({e})") from None
    return recording


def _log(
    recording: rr.RecordingStream | None, index: int, outcome: FrameOutcome, options: viewer.ViewOptions
) -> str:
    """Log one processed frame (with its ground truth when it has readable ground truth); the
    problem, if logging failed, else ""."""
    if recording is None:
        return ""
    assert outcome.prepared is not None and outcome.detections is not None
    frame, det = outcome.prepared.frame, outcome.detections
    gt = frame.truth
    try:
        viewer.load_view().log_frame(
            recording,
            index,
            color=frame.color,
            depth_m=frame.depth,
            K=frame.intrinsics,
            R_tilt=det.R_tilt,
            class_ids=det.class_ids,
            scores=det.scores,
            boxes2d=det.boxes2d,
            boxes3d=det.boxes3d,
            gt_class_ids=None if gt is None else gt.class_ids,
            gt_boxes3d=None if gt is None else gt.boxes3d,
            proposals=outcome.prepared.native_boxes,
            options=options,
        )
    except Exception as e:  # the line is written; a viewer problem must not stop the run
        return f"{frame.origin}: rerun: cannot log the frame ({type(e).__name__}: {e})"
    return ""


@contextlib.contextmanager
def _threads(n: int) -> Iterator[None]:
    """OpenCV's thread count for the run (restored after)."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


class _TqdmHandler(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        tqdm.write(f"{PROG}: warning: {record.getMessage()}", file=sys.stderr)


@contextlib.contextmanager
def _warnings_to_stderr() -> Iterator[None]:
    """a3d's logged warnings (e.g. a frame without valid depth) as one stderr line each, above the bar."""
    logger = logging.getLogger("a3d")
    handler = _TqdmHandler(logging.WARNING)
    logger.addHandler(handler)
    propagate, logger.propagate = logger.propagate, False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


if __name__ == "__main__":
    sys.exit(main())
