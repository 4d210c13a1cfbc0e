"""a3d-synth: write a synthetic RGB-D training and test set, or summarise one.

    a3d-synth OUT --frames N --seed S [--split test=0.3] [--workers K] [--size HxW] [--sensor kinect-v1]
        [--appearance typical] [--world real] [--clutter N] [--camera-mix all|NAME,...] [--camera-scale S]
        [--real-light | --no-real-light] [--empty-share F]
    a3d-synth OUT --sequence N --seed S [--loops 2] [--heights H[,H]] [--size HxW] [--sensor ...]
        [--camera-mix NAME] [--world ...] [--workers K]
    a3d-synth --stats OUT

Frame i of a run is rendered from ``frame_seed(S, i)``, so a set is the same whatever the number
of workers. Frames go to OUT/train and OUT/test (a random ``test`` share, also fixed by S) as
``synth_NNNNNN`` in the README frame format, each folder with its ``intrinsics.json``; one
statistics line per frame goes to OUT/synth_objects.jsonl (``a3d.synth.stats``).

``--world real`` (docs/synthetic-world.md) renders the cluttered world: WORLDS["real"] objects
of no class per room, a camera preset per frame from ``a3d.synth.devices`` (its size and
intrinsics in the frame's meta.json), daylight and a consumer colour pipeline, and a share of
rooms without any class object; each setting can be changed on its own. The default world
(``--world a3d``) renders the same frames as before these options existed.

``--sequence N`` renders one room (that of seed S) seen from N poses of a camera moving round it
(a3d.synth.sequence): OUT/frames holds ``seq_NNNNNN`` frames with their camera-to-world ``"pose"``
in meta.json and the usual ground truth, OUT/world_boxes.json the room's objects in its
gravity-aligned world (docs/mapping.md). One camera, so no split and no mix: ``--size`` and
``--sensor``, or one preset (``--camera-mix realsense-d435``: a user's RealSense, its size,
intrinsics and depth model in every frame). ``--loops 2`` goes round twice: a hand-held camera's
loop, then a robot's, lower and on another path (the room seen again by a robot working in it);
``--heights`` gives each loop's camera height in metres (``--loops 2 --heights 1.0,1.0``: a robot
recording its own room, both loops at its camera's height).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.mapping.world_boxes import WORLD_BOXES_FILE, write_world_boxes
from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS, NYU_CROP_SIZE, Intrinsics
from a3d.synth.camera import CameraPose
from a3d.synth.devices import DEVICES
from a3d.synth.scene import APPEARANCES, SceneConfig, generate_frame
from a3d.synth.sensor import SENSORS
from a3d.synth.sequence import LOOP_HEIGHTS_M, loop_heights, orbit, room_of, world_boxes, world_pose
from a3d.synth.stats import RECORDS_FILE, format_summary, frame_record, read_records, summarise


def frame_seed(seed: int, index: int) -> int:
    """The render seed of frame ``index`` of a run with seed ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1, np.uint64)[0] >> np.uint64(1))


WORLDS: dict[str, dict] = {
    "a3d": {"clutter": 0, "camera_mix": (), "real_light": False, "empty_share": 0.0},
    "real": {"clutter": 30, "camera_mix": tuple(DEVICES), "real_light": True, "empty_share": 0.1},
}
"""The defaults of the world options per ``--world``."""


def held_out_indices(seed: int, n: int, share: float, salt: int = 0x7E57) -> set[int]:
    """Which of frames 0..n-1 go to the test split (round(n * share) of them, fixed by seed);
    another ``salt`` draws another subset (the rooms without class objects)."""
    order = np.random.default_rng(np.random.SeedSequence([seed, salt])).permutation(n)
    return {int(i) for i in order[: round(n * share)]}


def frame_device(seed: int, index: int, mix: tuple[str, ...]) -> str:
    """The camera preset of frame ``index`` of a run (uniform over ``mix``, fixed by seed)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, index, 0xCA3]))
    return mix[int(rng.integers(len(mix)))]


def _parse_mix(text: str) -> tuple[str, ...]:
    names = tuple(DEVICES) if text == "all" else tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in DEVICES]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"--camera-mix: unknown camera {unknown[0]!r} (known: all, {', '.join(DEVICES)})"
        )
    return names


def scaled_intrinsics(size: tuple[int, int]) -> Intrinsics:
    """NYUv2 standard-crop intrinsics resampled to an image of ``size`` (H, W) (same field of view)."""
    H, W = size
    return NYU_CROP_INTRINSICS.resized(W / NYU_CROP_SIZE[1], H / NYU_CROP_SIZE[0])


def _parse_split(text: str) -> float:
    name, _, value = text.partition("=")
    try:
        share = float(value)
    except ValueError:
        share = -1.0
    if name != "test" or not 0.0 <= share <= 1.0:
        raise argparse.ArgumentTypeError(f"--split: expected test=SHARE with SHARE in [0, 1], got {text!r}")
    return share


def _parse_heights(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected metres as H or H,H, got {text!r}") from None


def _parse_size(text: str) -> tuple[int, int]:
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        h = w = 0
    if h < 16 or w < 16:
        raise argparse.ArgumentTypeError(f"--size: expected HxW with both >= 16, got {text!r}")
    return h, w


@dataclass(frozen=True)
class RenderJob:
    """One frame to render and write: ``camera`` (a sequence's view, a3d.synth.sequence) and
    ``noise_seed`` None for a frame of its own room and pose; ``own_intrinsics``: write them into
    its meta.json (a camera mix)."""

    folder: Path
    name: str
    split: str
    seed: int
    config: SceneConfig
    depth_format: str
    own_intrinsics: bool = False
    camera: CameraPose | None = None
    noise_seed: int | None = None


def _render_one(job: RenderJob) -> dict:
    frame = generate_frame(job.seed, job.config, camera=job.camera, noise_seed=job.noise_seed)
    write_frame(
        job.folder,
        job.name,
        frame.color,
        frame.depth,
        R_tilt=frame.R_tilt,
        intrinsics_override=job.config.intrinsics if job.own_intrinsics else None,
        gt=frame.gt,
        instances=frame.instances,
        depth_format=job.depth_format,
        pose=None if job.camera is None else world_pose(job.camera),
    )
    return frame_record(job.name, job.split, job.seed, frame)


def _init_worker() -> None:
    cv2.setNumThreads(1)  # one core per worker


def frame_configs(
    seed: int,
    frames: int,
    config: SceneConfig,
    camera_mix: tuple[str, ...] = (),
    camera_scale: float = 1.0,
    empty_share: float = 0.0,
) -> list[SceneConfig]:
    """The settings of frames 0..frames-1 of a run: ``config``, each with a camera preset of
    ``camera_mix`` (none: ``config``'s size and intrinsics) at ``camera_scale``, and for an
    ``empty_share`` of them (fixed by seed) a room without class objects."""
    empty = held_out_indices(seed, frames, empty_share, salt=0xE3)
    configs = []
    for i in range(frames):
        frame_config = replace(config, labelled=False) if i in empty else config
        if camera_mix:
            frame_config = device_config(frame_config, frame_device(seed, i, camera_mix), camera_scale)
        configs.append(frame_config)
    return configs


def device_config(config: SceneConfig, name: str, scale: float = 1.0) -> SceneConfig:
    """``config`` seen by camera preset ``name`` (a3d.synth.devices) at ``scale``: its frame size,
    intrinsics and depth model."""
    device = DEVICES[name]
    size, K = device.frame(scale)
    return replace(config, image_size=size, intrinsics=K, depth_sensor=device.depth, device=device.name)


def generate(
    out: Path,
    frames: int,
    seed: int,
    test_share: float,
    workers: int,
    config: SceneConfig,
    depth_format: str = "png",
    progress: bool = True,
    camera_mix: tuple[str, ...] = (),
    camera_scale: float = 1.0,
    empty_share: float = 0.0,
) -> list[dict]:
    """Render and write a set (see the module docstring); returns its statistics records.

    Frames take their settings from ``frame_configs``."""
    test = held_out_indices(seed, frames, test_share)
    configs = frame_configs(seed, frames, config, camera_mix, camera_scale, empty_share)
    jobs = []
    for i, frame_config in enumerate(configs):
        split = "test" if i in test else "train"
        name = f"synth_{i:06d}"
        job = RenderJob(
            out / split, name, split, frame_seed(seed, i), frame_config, depth_format, bool(camera_mix)
        )
        jobs.append(job)
    for split in ("train", "test"):
        (out / split).mkdir(parents=True, exist_ok=True)
        write_intrinsics(out / split, config.intrinsics)
    return _run_jobs(jobs, workers, progress, out / RECORDS_FILE)


def generate_sequence(
    out: Path,
    frames: int,
    seed: int,
    workers: int,
    config: SceneConfig,
    depth_format: str = "png",
    progress: bool = True,
    loops: int = 1,
    heights: tuple[float, ...] | None = None,
) -> list[dict]:
    """Render and write a posed sequence of one room (module docstring); returns its statistics records."""
    _, layout = room_of(seed, config)
    folder = out / "frames"
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder, config.intrinsics)
    write_world_boxes(out / WORLD_BOXES_FILE, world_boxes(layout))
    jobs = [
        RenderJob(
            folder, f"seq_{i:06d}", "sequence", seed, config, depth_format, False, camera, frame_seed(seed, i)
        )
        for i, camera in enumerate(orbit(layout, frames, loops, heights))
    ]
    return _run_jobs(jobs, workers, progress, out / RECORDS_FILE)


def _run_jobs(jobs: list[RenderJob], workers: int, progress: bool, records_file: Path) -> list[dict]:
    """Render the jobs in order (on ``workers`` processes), then write their statistics records."""
    bar = tqdm(total=len(jobs), desc="a3d-synth", unit="frame", disable=not progress)
    records = []
    if workers <= 1:
        _init_worker()
        for job in jobs:
            records.append(_render_one(job))
            bar.update()
    else:
        with multiprocessing.get_context("spawn").Pool(workers, initializer=_init_worker) as pool:
            for record in pool.imap(_render_one, jobs, chunksize=1):
                records.append(record)
                bar.update()
    bar.close()
    with records_file.open("w") as f:
        for record in records:
            f.write(json.dumps(record) + "\n")
    return records


PROG = "a3d-synth"


def build_parser() -> argparse.ArgumentParser:
    parser = command_parser(PROG, __doc__.split("\n\n")[0])
    parser.add_argument(
        "out", nargs="?", type=Path, help="output folder (gets train/, test/ and the statistics)"
    )
    parser.add_argument("--frames", type=int, default=100, help="number of frames")
    parser.add_argument(
        "--sequence",
        type=int,
        metavar="N",
        help="one room seen from N poses of a moving camera instead (OUT/frames, OUT/world_boxes.json)",
    )
    parser.add_argument(
        "--loops",
        type=int,
        choices=(1, 2),
        default=1,
        help="a --sequence's loops round the room: 1 hand-held; 2: then a robot's, lower, on another path",
    )
    parser.add_argument(
        "--heights",
        type=_parse_heights,
        metavar="H[,H]",
        help=f"each loop's camera height in metres (default {', then '.join(map(str, LOOP_HEIGHTS_M))});"
        " a lower camera looks down less",
    )
    parser.add_argument("--seed", type=int, default=0, help="run seed")
    parser.add_argument(
        "--split",
        type=_parse_split,
        default=0.3,
        metavar="test=SHARE",
        help="share of frames in the test split (default: test=0.3)",
    )
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument(
        "--size",
        type=_parse_size,
        metavar="HxW",
        help="image size; the NYUv2 crop intrinsics are scaled to it (default: 427x561)",
    )
    parser.add_argument(
        "--min-visible-px",
        type=int,
        default=SceneConfig.min_visible_px,
        help="objects with fewer visible pixels are not annotated",
    )
    parser.add_argument(
        "--sensor",
        choices=tuple(SENSORS),
        default="a3d",
        help="depth error model (a3d.synth.sensor): a3d, or kinect-v1's full error",
    )
    parser.add_argument(
        "--appearance",
        choices=APPEARANCES,
        default="independent",
        help="materials drawn whatever the class (independent), or class-typical (a3d.synth.appearance)",
    )
    parser.add_argument(
        "--depth-format",
        choices=("png", "npy"),
        default="png",
        help="png: uint16 millimetres; npy: float32 metres (docs/formats.md 'Frame format')",
    )
    parser.add_argument(
        "--world",
        choices=tuple(WORLDS),
        default="a3d",
        help="a3d (the classes only) or real: clutter, camera mix, real light, empty rooms",
    )
    parser.add_argument(
        "--clutter", type=int, help="objects of no class added per room (default: the world's)"
    )
    parser.add_argument(
        "--camera-mix",
        type=_parse_mix,
        metavar="all|NAME,...",
        help=f"camera presets drawn per frame, instead of --size ({', '.join(DEVICES)}); "
        "a --sequence takes one",
    )
    parser.add_argument("--camera-scale", type=float, default=1.0, help="scale of the presets' frame size")
    parser.add_argument(
        "--real-light",
        action=argparse.BooleanOptionalAction,
        help="daylight, glowing windows and a consumer camera's colour pipeline (default: the world's)",
    )
    parser.add_argument(
        "--empty-share", type=float, help="share of rooms without class objects (default: the world's)"
    )
    parser.add_argument(
        "--stats", type=Path, metavar="FOLDER", help="print the statistics of a generated set and exit"
    )
    return parser


@command(PROG, errors=(OSError, ValueError))
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.stats is not None:
        print(format_summary(summarise(read_records(args.stats))))  # OSError, ValueError: exit 2
        return 0
    if args.out is None:
        parser.error("give an output folder, or --stats FOLDER")
    if args.frames < 1 or args.workers < 1 or args.min_visible_px < 1:
        parser.error("--frames, --workers and --min-visible-px must be >= 1")
    world = {k: v if getattr(args, k) is None else getattr(args, k) for k, v in WORLDS[args.world].items()}
    if world["clutter"] < 0 or not 0.0 <= world["empty_share"] <= 1.0 or not 0.05 <= args.camera_scale <= 4:
        parser.error("--clutter must be >= 0, --empty-share in [0, 1] and --camera-scale in [0.05, 4]")
    if args.sequence is not None and (args.sequence < 1 or len(args.camera_mix or ()) > 1):
        parser.error("--sequence must be >= 1 and is seen by one camera: --size, or one --camera-mix preset")
    if args.loops != 1 and (args.sequence is None or args.sequence < args.loops):
        parser.error("--loops 2 takes a --sequence of 2 or more frames")
    if args.heights is not None:
        if args.sequence is None:
            parser.error("--heights takes a --sequence")
        try:
            loop_heights(args.loops, args.heights)
        except ValueError as e:
            parser.error(f"--{e} (--loops {args.loops})")
    if args.sequence is not None:
        world["camera_mix"] = args.camera_mix or ()
    if world["camera_mix"] and (args.size is not None or args.sensor != "a3d"):
        parser.error(
            "--size and --sensor exclude a camera mix: each preset has its own size and depth model"
            " (use --camera-scale, or --camera-mix '')"
        )
    size = args.size or NYU_CROP_SIZE
    config = replace(
        SceneConfig(),
        image_size=size,
        intrinsics=scaled_intrinsics(size),
        min_visible_px=args.min_visible_px,
        depth_sensor=SENSORS[args.sensor],
        appearance=args.appearance,
        clutter=world["clutter"],
        real_light=world["real_light"],
    )
    if args.sequence is not None:
        if world["camera_mix"]:
            config = device_config(config, world["camera_mix"][0], args.camera_scale)
        records = generate_sequence(
            args.out, args.sequence, args.seed, args.workers, config, args.depth_format,
            loops=args.loops, heights=args.heights,
        )  # fmt: skip
        print(format_summary(summarise(records)))
        return 0
    records = generate(
        args.out,
        args.frames,
        args.seed,
        args.split,
        args.workers,
        config,
        args.depth_format,
        camera_mix=world["camera_mix"],
        camera_scale=args.camera_scale,
        empty_share=world["empty_share"],
    )
    print(format_summary(summarise(records)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
