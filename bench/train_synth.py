"""Train a CPU configuration on a3d-synth data and score it on the held-out split with a3d-eval.

    .venv/bin/python -m bench.train_synth --out out/bench_train_synth [--frames 300] [--config cpu-small]
        [--iters N] [--set KEY=VALUE ...] [--val-frames 20] [--resume]

Steps (each timed, wall clock): a3d-synth OUT/data --frames N --split test=T (skipped when
OUT/data exists); a3d-train OUT/data/train --out OUT/run (with periodic validation on the first
--val-frames test frames); detections of every test frame through the torch reference path
(a3d.train.inference, the runtime's pipeline with the eager network) into OUT/detections.jsonl;
a3d-eval OUT/data/test on them (OUT/eval/eval.json). Prints and writes OUT/summary.json with the
mAP@0.25 over the 19 classes (the paper's number) and over the classes present.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def run(command: list[str], log: Path | None = None) -> float:
    """Run a command (output to ``log`` when given, else inherited); seconds taken; exit on failure."""
    print("$", " ".join(command), flush=True)
    t0 = time.perf_counter()
    if log is None:
        code = subprocess.run(command).returncode
    else:
        with open(log, "a", encoding="utf-8") as f:
            code = subprocess.run(command, stdout=f, stderr=subprocess.STDOUT).returncode
    if code != 0:
        sys.exit(f"failed ({code}): {' '.join(command)}" + (f" (see {log})" if log else ""))
    return time.perf_counter() - t0


def synthesize(
    data: Path, frames: int, seed: int, test_share: float, options: list[str] = ()
) -> float | None:
    """a3d-synth DATA (with more a3d-synth ``options``) unless DATA/train exists; wall seconds or None."""
    if (data / "train").is_dir():
        print(f"using the existing {data}")
        return None
    return run([str(BIN / "a3d-synth"), str(data), "--frames", str(frames), "--seed", str(seed),
                "--split", f"test={test_share}", *options])  # fmt: skip


def train(train_dir: Path, run_dir: Path, config: str | None, sets: list[str], iters: int | None,
          val_dir: Path | None, resume: bool, device: str | None) -> float:  # fmt: skip
    """a3d-train as a subprocess (as a user runs it); wall seconds."""
    command = [str(BIN / "a3d-train"), str(train_dir), "--out", str(run_dir)]
    if resume:
        command.append("--resume")
    elif config:
        command += ["--config", config]
    for s in sets:
        command += ["--set", s]
    if iters:
        command += ["--iters", str(iters)]
    if val_dir is not None:
        command += ["--val", str(val_dir)]
    if device:
        command += ["--device", device]
    return run(command)


def detect_and_score(checkpoint: Path, test_dir: Path, out: Path, overrides: list[str] = (),
                     device: str = "cpu") -> dict:  # fmt: skip
    """Torch-path detections of the test frames, scored by a3d-eval; the numbers and timings."""
    from a3d.train.checkpoint import checkpoint_config
    from a3d.train.config import apply_overrides
    from a3d.train.inference import TorchDetector, write_folder_detections

    config = apply_overrides(checkpoint_config(checkpoint), list(overrides))
    detector = TorchDetector.from_checkpoint(checkpoint, device, config)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    frames, problems = write_folder_detections(detector, test_dir, out / "detections.jsonl")
    detect_s = time.perf_counter() - t0
    for problem in problems:
        print("skipped:", problem)
    eval_s = run([str(BIN / "a3d-eval"), str(test_dir), "--detections", str(out / "detections.jsonl"),
                  "--out", str(out / "eval")], log=out / "eval.log")  # fmt: skip
    report = json.loads((out / "eval" / "eval.json").read_text())
    stages: dict[str, float] = {}
    for f in frames:
        for k, v in f.timing.items():
            stages[k] = stages.get(k, 0.0) + v / max(len(frames), 1)
    return {
        **scores_of(report),
        "test_frames": len(frames),
        "detect_seconds": detect_s,
        "seconds_per_frame": {k: round(v, 4) for k, v in stages.items()},
        "eval_seconds": eval_s,
    }


def run_and_score(
    model: Path, test_dir: Path, out: Path, threads: int | None = None, reuse: bool = False
) -> dict:
    """An exported model's detections of the test frames through a3d-run (--headless, the model's
    own settings; ``threads`` ONNX Runtime threads, default a3d-run's) in OUT/detections.jsonl,
    scored by a3d-eval in OUT/eval: detect_and_score's numbers for an ONNX file. With ``reuse``
    detections already in OUT are scored again (detect_seconds NaN)."""
    out.mkdir(parents=True, exist_ok=True)
    detections = out / "detections.jsonl"
    detect_s = math.nan
    if not (reuse and detections.is_file()):
        command = [str(BIN / "a3d-run"), str(test_dir), "--model", str(model), "--output", str(detections),
                   "--headless", *(["--threads", str(threads)] if threads else [])]  # fmt: skip
        detect_s = run(command, log=out / "run.log")
    eval_s = run([str(BIN / "a3d-eval"), str(test_dir), "--detections", str(detections),
                  "--out", str(out / "eval")], log=out / "eval.log")  # fmt: skip
    report = json.loads((out / "eval" / "eval.json").read_text())
    return {**scores_of(report), "detect_seconds": detect_s, "eval_seconds": eval_s}


def scores_of(report: dict) -> dict:
    """mAP@0.25 (19 classes, present classes), mAP@0.5, per-class AP@0.25 and the annotated frame
    count of an a3d-eval report (eval.json)."""
    return {
        "map25_all": report["map"]["0.25"]["all_classes"],
        "map25_present": report["map"]["0.25"]["present_classes"],
        "map50_all": report["map"]["0.5"]["all_classes"],
        "ap25": {c: v["ap"]["0.25"] for c, v in report["classes"].items() if v["present"]},
        "test_frames": report["inputs"]["frames_with_gt"],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench_train_synth"))
    parser.add_argument("--frames", type=int, default=300, help="a3d-synth frames (train + test)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--test-share", type=float, default=0.2)
    parser.add_argument("--config", default="cpu-small")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--iters", type=int)
    parser.add_argument("--val-frames", type=int, default=20, help="test frames for validation (0: none)")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--device")
    args = parser.parse_args()

    data, run_dir = args.out / "data", args.out / "run"
    summary: dict = {"config": args.config, "sets": args.sets, "frames": args.frames}
    summary["synth_seconds"] = synthesize(data, args.frames, args.seed, args.test_share)
    sets = [*args.sets, f"data.cache_dir={args.out / 'cache'}"]
    val_dir = data / "test" if args.val_frames > 0 else None
    if val_dir is not None:
        sets.append(f"log.val_frames={args.val_frames}")
    summary["train_seconds"] = train(data / "train", run_dir, args.config, sets, args.iters, val_dir,
                                     args.resume, args.device)  # fmt: skip
    checkpoint = run_dir / "checkpoint.pt"
    summary.update(detect_and_score(checkpoint, data / "test", args.out, device=args.device or "cpu"))
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps({k: v for k, v in summary.items() if k != "ap25"}, indent=1))
    print(
        f"mAP@0.25 over 19 classes: {100 * summary['map25_all']:.1f}   "
        f"(present classes: {100 * summary['map25_present']:.1f}); "
        f"train {summary['train_seconds'] / 60:.1f} min"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
