"""The real-model ablation in one command: the same frames, several colour-trunk recipes, each
scored on held-out synthetic frames and on real frames (docs/real-model.md "Measured").

    python -m bench.real_model_ablation --work W --weights vgg16_imagenet.pt --real REAL_FRAMES \\
        --out OUT [--frames 1600] [--val-frames 150] [--held-out 350] [--iters 6000] \\
        [--variants frozen,frozen-aug,conv5-aug,all-aug] [--deadline-s 0] [--device cuda]

Steps: a3d-synth makes (once per W) the training frames
(two thirds of ``--frames`` the real-appearance world at seed 0, one third at seed 8 with half the
rooms empty), the score-calibration frames (seed 1) and the held-out frames (seed 2027, the
README's 350); one a3d-train pass caches every training frame's proposals; then every variant
trains at once on the same data and cache, from ``cpu-imagenet`` (full-width ImageNet colour trunk
beside cpu-small's depth trunk and head) with its own settings (VARIANTS); each is exported fp32
with its score calibration and scored: a3d-run + a3d-eval on the held-out frames (mAP@0.25 and
@0.5), bench.false_positives (detections >= 0.5 per empty room) and bench.real_frames at 0.5 and
0.3 against the hand-drawn boxes. Prints the table and writes OUT/ablation.json and each
variant's contact sheet at 0.5 (OUT/VARIANT.jpg).

``--deadline-s`` fits the run to a wall-clock budget: training gets what is left after the data
and a reserve for scoring, split evenly as ``--minutes`` among the variants that train at once.
The processes share the machine's cores: ``--workers`` DataLoader workers each (default: cores /
variants - 1). ``--score-only`` scores the runs already in W/runs (e.g. after a deadline cut the
scoring short).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from importlib.metadata import entry_points
from pathlib import Path

import cv2

VARIANTS: dict[str, list[str]] = {
    "frozen": [],  # the CPU-hour recipe: all 13 convs fixed, features cached
    "frozen-aug": ["data.augment=true"],  # the same, trained on augmented colour and depth
    "conv5-aug": ["solver.freeze_color=10", "solver.color_lr_mult=0.1", "data.augment=true"],
    "all-aug": ["solver.freeze_color=0", "solver.color_lr_mult=0.1", "data.augment=true"],
    "conv5": ["solver.freeze_color=10", "solver.color_lr_mult=0.1"],
}
LR_STEP_SHARE = 0.8  # lr x0.1 after this share of the run (cpu-small: 3800 of 5000)
SCORING_RESERVE_S = 240.0  # export with score calibration, held-out and real frames: 4 variants, 16 cores


def _bin(name: str) -> list[str]:
    """A console script of the installed package (pyproject's [project.scripts]), run by its
    module so no PATH is needed (a --target install on a lent machine has no scripts on PATH)."""
    (script,) = entry_points(group="console_scripts", name=name)
    return [sys.executable, "-m", script.module]


def _run(cmd: list[str], log: Path) -> str:
    """Run ``cmd`` with its output in ``log``; its last lines on failure (then RuntimeError)."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as f:
        code = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    text = log.read_text(errors="replace")
    if code != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} ... exited {code}: {text[-800:]}")
    return text


def make_data(work: Path, frames: int, val_frames: int, held_out: int, workers: int) -> list[Path]:
    """The synthetic sets (skipped where present); returns the training folders."""
    first = round(frames * 2 / 3)
    sets = [
        ("a", ["--frames", str(first), "--seed", "0", "--split", "test=0"]),
        ("b", ["--frames", str(frames - first), "--seed", "8", "--split", "test=0", "--empty-share", "0.5"]),
        ("val", ["--frames", str(val_frames), "--seed", "1", "--split", "test=1"]),
        ("h350", ["--frames", str(held_out), "--seed", "2027", "--split", "test=1"]),
    ]
    for name, args in sets:
        folder = work / name
        if not (folder / "synth_objects.jsonl").is_file():
            _run(
                [*_bin("a3d-synth"), str(folder), *args, "--world", "real", "--workers", str(workers)],
                work / "logs" / f"synth_{name}.log",
            )
    return [work / "a" / "train", work / "b" / "train"]


def train_args(
    data: list[Path], out: Path, weights: Path, cache: Path, device: str, extra: list[str]
) -> list[str]:
    sets = [
        "solver.pretrained=" + str(weights),
        "data.images_per_batch=4",
        "solver.precision=bf16",
        "data.bg_iou_low=0",
        f"data.cache_dir={cache}",
        "log.progress=false",
        *extra,
    ]
    cmd = [*_bin("a3d-train"), *map(str, data), "--out", str(out), "--config", "cpu-imagenet", "--force"]
    cmd += ["--device", device] if device else []
    for item in sets:
        cmd += ["--set", item]
    return cmd


def score(work: Path, name: str, real: Path, boxes: Path, threads: int) -> dict:
    """Export one variant fp32 with its score calibration, then the held-out and real-frame numbers."""
    run, ev = work / "runs" / name, work / "eval" / name
    model = run / "model.onnx"
    logs = work / "logs"
    _run(
        [
            *_bin("a3d-export"),
            str(run / "checkpoint.pt"),
            "-o",
            str(model),
            "--threads",
            str(threads),
            "--score-calibration",
            str(work / "val" / "test"),
        ],
        logs / f"export_{name}.log",
    )
    detections = ev / "h350.jsonl"
    _run(
        [
            *_bin("a3d-run"),
            str(work / "h350" / "test"),
            "--model",
            str(model),
            "--headless",
            "--threads",
            str(threads),
            "--output",
            str(detections),
        ],
        logs / f"run_{name}.log",
    )
    _run(
        [
            *_bin("a3d-eval"),
            str(work / "h350" / "test"),
            "--detections",
            str(detections),
            "--out",
            str(ev / "h350_eval"),
        ],
        logs / f"eval_{name}.log",
    )
    maps = json.loads((ev / "h350_eval" / "eval.json").read_text())["map"]
    fp = (
        _run(
            [
                sys.executable,
                "-m",
                "bench.false_positives",
                str(work / "h350" / "test"),
                "--detections",
                str(detections),
            ],
            logs / f"fp_{name}.log",
        )
        .strip()
        .splitlines()[-1]
    )
    result = {"held_out_map": maps, "false_positives": fp}
    for threshold in (0.5, 0.3):
        out = ev / f"real_{threshold}"
        _run(
            [
                sys.executable,
                "-m",
                "bench.real_frames",
                str(real),
                "--model",
                str(model),
                "--model-name",
                name,
                "--boxes",
                str(boxes),
                "--threshold",
                str(threshold),
                "--threads",
                str(threads),
                "--out",
                str(out),
            ],
            logs / f"real_{name}_{threshold}.log",
        )
        result[f"real_{threshold}"] = json.loads((out / "real_frames.json").read_text())["total"]
    return result


def _iterations(run: Path) -> int:
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines() if x.strip()]
    return max((r.get("iter", 0) for r in lines), default=0)


def train_variants(
    args: argparse.Namespace, names: list[str], data: list[Path], cores: int, start: float
) -> list[str]:
    """Cache the proposals once, then train every variant at once; the names of those that finished."""
    cache = args.work / "cache"
    _run(
        [*train_args(data, args.work / "cachepass", args.weights, cache, args.device, []), "--iters", "1"],
        args.work / "logs" / "cachepass.log",
    )
    print(f"proposals cached at {time.monotonic() - start:.0f} s", flush=True)
    workers = args.workers or max(1, cores // len(names) - 1)
    budget = []
    if args.deadline_s:
        left = args.deadline_s - (time.monotonic() - start) - SCORING_RESERVE_S
        budget = ["--minutes", f"{max(left, 60.0) / 60.0:.2f}"]
    procs = {}
    for name in names:
        extra = [
            *VARIANTS[name],
            f"data.workers={workers}",
            f"solver.threads={max(1, cores // len(names))}",
            f"solver.lr_steps=[{round(LR_STEP_SHARE * args.iters)}]",  # scaled with a --minutes fit
        ]
        cmd = train_args(data, args.work / "runs" / name, args.weights, cache, args.device, extra)
        log = args.work / "logs" / f"train_{name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        procs[name] = subprocess.Popen(
            [*cmd, "--iters", str(args.iters), *budget], stdout=open(log, "w"), stderr=subprocess.STDOUT
        )
    codes = {n: p.wait() for n, p in procs.items()}
    trained = [n for n, code in codes.items() if code == 0]
    for n in sorted(set(names) - set(trained)):
        tail = (args.work / "logs" / f"train_{n}.log").read_text()[-600:]
        print(f"{n}: training failed: {tail}", flush=True)
    print(f"trained {', '.join(trained)} at {time.monotonic() - start:.0f} s", flush=True)
    return trained


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--weights", type=Path, required=True, help="a3d-vgg16-weights output")
    parser.add_argument("--real", type=Path, required=True, help="folder of real frames")
    parser.add_argument(
        "--boxes", type=Path, default=Path(__file__).parent / "data" / "real_frames_boxes.json"
    )
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=1600)
    parser.add_argument("--val-frames", type=int, default=150)
    parser.add_argument("--held-out", type=int, default=350)
    parser.add_argument("--iters", type=int, default=6000)
    parser.add_argument("--variants", default="frozen,frozen-aug,conv5-aug,all-aug")
    parser.add_argument("--deadline-s", type=float, default=0.0)
    parser.add_argument("--device", default="")
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--score-only", action="store_true", help="score the runs already in WORK/runs")
    args = parser.parse_args()
    names = args.variants.split(",")
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        parser.error(f"--variants: unknown {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    start, cores = time.monotonic(), len(os.sched_getaffinity(0))
    args.out.mkdir(parents=True, exist_ok=True)
    data = make_data(args.work, args.frames, args.val_frames, args.held_out, cores)
    print(f"data ready at {time.monotonic() - start:.0f} s", flush=True)
    if args.score_only:
        trained = [n for n in names if (args.work / "runs" / n / "checkpoint.pt").is_file()]
    else:
        trained = train_variants(args, names, data, cores, start)
    threads = max(1, cores // max(1, len(trained)))
    with ThreadPoolExecutor(len(trained) or 1) as pool:
        futures = {n: pool.submit(score, args.work, n, args.real, args.boxes, threads) for n in trained}
    results = {}
    for name, future in futures.items():
        try:
            results[name] = {"iterations": _iterations(args.work / "runs" / name), **future.result()}
        except RuntimeError as e:
            results[name] = {"error": str(e)}
        sheet = args.work / "eval" / name / "real_0.5" / "contact_sheet.png"
        if sheet.is_file():
            cv2.imwrite(str(args.out / f"{name}.jpg"), cv2.imread(str(sheet)), [cv2.IMWRITE_JPEG_QUALITY, 80])
    (args.out / "ablation.json").write_text(json.dumps(results, indent=2))
    print(
        "| variant | iterations | held out mAP@0.25 (0.5) | per empty room "
        "| real >= 0.5 found, right/det | real >= 0.3 |"
    )
    for name, r in results.items():
        if "error" in r:
            print(f"| {name} | error: {r['error'][:200]} |")
            continue
        m, a, b = r["held_out_map"], r["real_0.5"], r["real_0.3"]
        held = f"{100 * m['0.25']['all_classes']:.1f} ({100 * m['0.5']['all_classes']:.1f})"
        empty = r["false_positives"].split(":")[1].split()[0]
        print(
            f"| {name} | {r['iterations']} | {held} | {empty} | {a['found']} of {a['objects']}; "
            f"{a['right']}/{a['detections']} | {b['found']}; {b['right']}/{b['detections']} |"
        )
    print(f"done at {time.monotonic() - start:.0f} s", flush=True)
    return 0 if len(results) == len(names) and not any("error" in r for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
