"""Transfer: train on one synthetic world, test on every other, and report what the change costs.

    .venv/bin/python -m bench.transfer --out out/bench_transfer [--worlds plain,clutter,kinect-v1,tof]
        [--frames 300] [--test-share 0.2] [--scale 1] [--config cpu-small] [--iters N] [--set KEY=VALUE ...]
        [--model WORLD=MODEL ...] [--test WORLD=FOLDER ...]

A model that fits its own world can still fail on another: a held-out split of the training
world measures fit, not transfer. For each world (``WORLDS``: a3d-synth options, e.g. without
and with clutter, one depth-sensor family and another, class-free and class-typical appearance)
this renders a set (bench/train_synth.py's steps: a3d-synth, a3d-train), then scores every
trained model on every world's test split (torch-path detections, a3d-eval) and, where the test
split has frames without annotations, counts the detections >= 0.5 on them
(bench/false_positives.py). ``--scale`` shrinks the frames (the NYUv2 crop size, or the camera
presets' size) for quick runs.

``--model WORLD=MODEL`` takes an existing model as WORLD's instead of training one: an exported
ONNX file (scored through a3d-run --headless with its own settings, e.g. a bundled int8 model)
or a run folder or checkpoint (torch path). ``--test WORLD=FOLDER`` takes an existing folder of
frames with ground truth as WORLD's test split (e.g. 350 held-out frames). A world with both is
not rendered at all.

The table: rows the training world, columns the test world, mAP@0.25 over the 19 classes. The
drop of A -> B is mAP(B -> B) - mAP(A -> B): what training on A instead of B costs on B. Written
to OUT/transfer.json and printed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bench.false_positives import by_frame, count_false_positives
from bench.train_synth import detect_and_score, run_and_score, synthesize, train

NYU_SIZE = (427, 561)
WORLDS: dict[str, list[str]] = {
    "plain": [],
    "plain-v1": ["--sensor", "kinect-v1"],  # the first bundled model's world (README "Training")
    "clutter": ["--clutter", "30", "--empty-share", "0.1"],
    "typical": ["--appearance", "typical"],
    "kinect-v1": ["--camera-mix", "kinect-v1"],
    "tof": ["--camera-mix", "kinect-v2,azure-kinect"],
    "stereo": ["--camera-mix", "realsense-d435,realsense-d455"],
    "real": ["--world", "real"],
}
"""World name -> a3d-synth options (plain: the default a3d world)."""


def world_options(name: str, scale: float) -> list[str]:
    """a3d-synth options of world ``name`` at frame scale ``scale``."""
    options = WORLDS[name]
    if "--camera-mix" in options or "--world" in options:
        return [*options, "--camera-scale", str(scale)]
    h, w = (max(16, round(s * scale)) for s in NYU_SIZE)
    return [*options, "--size", f"{h}x{w}"]


def world_paths(pairs: list[str], flag: str, worlds: list[str]) -> dict[str, Path]:
    """``WORLD=PATH`` arguments of ``flag`` as {world: path}; ValueError names the bad one."""
    paths = {}
    for pair in pairs:
        world, sep, path = pair.partition("=")
        if not sep or world not in worlds or not Path(path).exists():
            raise ValueError(f"{flag} {pair!r}: give WORLD=PATH with WORLD one of --worlds and PATH existing")
        paths[world] = Path(path)
    return paths


def score(model: Path, test_dir: Path, out: Path, device: str) -> dict:
    """mAP and timings of ``model`` (ONNX file, run folder or checkpoint) on ``test_dir``."""
    if model.suffix == ".onnx":
        return run_and_score(model, test_dir, out)
    checkpoint = model / "checkpoint.pt" if model.is_dir() else model
    return detect_and_score(checkpoint, test_dir, out, device=device)


def drops(table: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """drop[A][B] = table[B][B] - table[A][B] for every A != B (in mAP points)."""
    return {a: {b: table[b][b] - row[b] for b in row if b != a} for a, row in table.items()}


def format_table(table: dict[str, dict[str, float]], worlds: list[str]) -> str:
    """The mAP@0.25 table (percent) and the drop of each cross-world entry."""
    d = drops(table)
    width = max(len(w) for w in worlds) + 2
    lines = ["train \\ test".ljust(width + 2) + "".join(w.rjust(width + 10) for w in worlds)]
    for a in worlds:
        cells = []
        for b in worlds:
            cell = f"{100 * table[a][b]:.1f}" + ("" if a == b else f" ({-100 * d[a][b]:+.1f})")
            cells.append(cell.rjust(width + 10))
        lines.append(a.ljust(width + 2) + "".join(cells))
    lines.append("mAP@0.25 over 19 classes; (drop) = cross-world minus the test world's in-world score")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench_transfer"))
    parser.add_argument("--worlds", default="plain,clutter", help=f"comma list of {', '.join(WORLDS)}")
    parser.add_argument("--frames", type=int, default=300, help="a3d-synth frames per world (train + test)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--test-share", type=float, default=0.2)
    parser.add_argument("--scale", type=float, default=1.0, help="frame size scale")
    parser.add_argument("--config", default="cpu-small")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--iters", type=int)
    parser.add_argument("--device")
    parser.add_argument("--model", dest="models", action="append", default=[], metavar="WORLD=MODEL",
                        help="WORLD's model (ONNX, run folder, checkpoint), not trained")  # fmt: skip
    parser.add_argument("--test", dest="tests", action="append", default=[], metavar="WORLD=FOLDER",
                        help="WORLD's test frames (a folder with ground truth)")  # fmt: skip
    args = parser.parse_args(argv)
    worlds = [w.strip() for w in args.worlds.split(",") if w.strip()]
    unknown = [w for w in worlds if w not in WORLDS]
    if unknown or len(worlds) < 2:
        parser.error(f"--worlds: give two or more of {', '.join(WORLDS)} (got {args.worlds!r})")
    try:
        models = world_paths(args.models, "--model", worlds)
        tests = world_paths(args.tests, "--test", worlds)
    except ValueError as e:
        parser.error(str(e))

    summary: dict = {
        "worlds": {w: WORLDS[w] for w in worlds},
        "frames": args.frames,
        "config": args.config,
        "sets": args.sets,
        "scale": args.scale,
        "scores": {},
        "false_positives": {},
        "models": {w: str(p) for w, p in models.items()},
        "tests": {w: str(p) for w, p in tests.items()},
    }
    for w in worlds:  # the data first: every model is tested on every world
        if w not in models or w not in tests:
            synthesize(
                args.out / w / "data", args.frames, args.seed, args.test_share, world_options(w, args.scale)
            )
    table: dict[str, dict[str, float]] = {}
    for a in worlds:
        model = models.get(a, args.out / a / "run")
        sets = [*args.sets, f"data.cache_dir={args.out / a / 'cache'}"]
        if a not in models and not (model / "checkpoint.pt").is_file():
            train(args.out / a / "data" / "train", model, args.config, sets, args.iters, None, False,
                  args.device)  # fmt: skip
        table[a] = {}
        for b in worlds:
            test_dir, out = tests.get(b, args.out / b / "data" / "test"), args.out / a / f"on_{b}"
            scores = score(model, test_dir, out, args.device or "cpu")
            table[a][b] = scores["map25_all"]
            summary["scores"][f"{a}->{b}"] = scores
            summary["false_positives"][f"{a}->{b}"] = count_false_positives(
                test_dir, by_frame(out / "detections.jsonl")
            )
    summary["map25"] = table
    summary["drop"] = drops(table)
    (args.out / "transfer.json").write_text(json.dumps(summary, indent=1))
    print(format_table(table, worlds))
    for key, fp in summary["false_positives"].items():
        if fp is not None:
            print(
                f"{key}: detections >= 0.5 per frame without annotations: {fp['per_frame']:.2f} "
                f"({fp['empty_frames']} frames)"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
