"""The paper's ablation (Table 2) on a data set: what depth, context and 3D regression contribute.

    .venv/bin/python -m bench.ablation TRAIN_DIR TEST_DIR --out out/ablation [--config cpu-small]
        [--iters N] [--set KEY=VALUE ...] [--only full,color,no-context,no-3dreg]
        [--full RUN_DIR] [--parallel N] [--bootstrap 100] [--reuse] [--per-class]

Variants (all with the same configuration otherwise, each trained from scratch into OUT/VARIANT):
  full        colour + depth + context + 3D regression          (paper: 40.9)
  color       colour only: one trunk, no context box              (paper: "img" 30.0)
              (net.use_depth=false, net.use_context=false)
  no-context  colour + depth without the context box            (paper: "img+d" 40.1)
  no-3dreg    the full model's detections with their initial boxes, i.e. no 3D regression
              (inference.regress_3d=false; no training)           (paper: 15.5)
and, with --only, rows for a3d's departures from the paper (paper column empty):
  no-trunk-bn no BatchNorm in the trunks, at the paper's lr 0.005 (net.trunk_norm=false)
  no-fuse     the paper's plain concatenation of the pooled blocks (net.fuse_channels=null)
  roi-max     the paper's max RoI pooling instead of RoIAlign (net.roi_pool=max)
Each is scored with a3d-eval at 3D IoU 0.25 (mAP over the 19 classes) on TEST_DIR, through the
torch reference path. Prints the table and writes OUT/ablation.json (merged with the variants
an earlier call scored there).

--full RUN_DIR takes an existing run (e.g. the 60-minute a3d-train run) as the full model
instead of training one; the other variants are then trained with that run's configuration
(its config.json), so they differ from it only in the ablated setting. --parallel N trains up to
N variants at once, each with cores / N torch threads and its data loading in-process (on 2
cores two single-thread runs do about 1.3x the iterations per second of one two-thread run);
iterations and every other setting are unchanged. A variant whose run folder already has a
checkpoint is resumed (to its configured length) rather than retrained. --bootstrap N adds,
per variant, a 90 % interval of (full - variant) in points over N paired resamples of the test
frames (bench/int8_accuracy.py's bootstrap; about 1 s per variant and resample on 350 frames).
--reuse keeps a variant's scores from an earlier call (OUT/eval-VARIANT) instead of detecting again.
With the four Table 2 rows scored, the paper's conclusions are checked on its steps (depth:
colour only -> no-context; context: no-context -> full; 3D regression: no-3dreg -> full), each
difference with its paired interval from the same resamples: 3D regression's gain minus depth's
and minus context's, depth's gain, context's gain. --per-class prints AP@0.25 per class, ours
beside the paper's.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from a3d.runtime.structures.classes import CLASSES
from bench.int8_accuracy import bootstrap_maps, interval_90
from bench.paper_table2 import PAPER_AP, PAPER_MAP
from bench.train_synth import BIN, detect_and_score, scores_of

VARIANTS = {  # name: (training --set overrides, inference overrides)
    "full": ([], []),
    "color": (["net.use_depth=false", "net.use_context=false"], []),
    "no-context": (["net.use_context=false"], []),
    "no-3dreg": (None, ["inference.regress_3d=false"]),  # None: the full model's checkpoint
}
TABLE_2 = ",".join(VARIANTS)
DEPARTURES = {  # rows for a3d's departures from the paper (README "Training"); not in the paper
    "no-trunk-bn": (["net.trunk_norm=false", "solver.lr=0.005"], []),
    "no-fuse": (["net.fuse_channels=null"], []),
    "roi-max": (["net.roi_pool=max"], []),
}
VARIANTS.update(DEPARTURES)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("train_dir", type=Path)
    parser.add_argument("test_dir", type=Path)
    parser.add_argument("--out", type=Path, default=Path("out/ablation"))
    parser.add_argument("--config", default="cpu-small", help="preset or file (ignored with --full)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--iters", type=int)
    parser.add_argument("--only", default=TABLE_2, help=f"comma-separated variants of {', '.join(VARIANTS)}")
    parser.add_argument("--full", type=Path, help="an existing run folder to score as the full model")
    parser.add_argument("--parallel", type=int, default=1, help="variants trained at once")
    parser.add_argument("--bootstrap", type=int, default=0,
                        help="paired resamples (90 %% interval of full - variant)")  # fmt: skip
    parser.add_argument("--per-class", action="store_true", help="AP per class beside Table 2's")
    parser.add_argument("--reuse", action="store_true", help="keep the scores already in OUT/eval-VARIANT")
    parser.add_argument("--device")
    args = parser.parse_args()
    chosen = args.only.split(",")
    unknown = sorted(set(chosen) - set(VARIANTS))
    if unknown:
        parser.error(f"unknown variants {unknown}; known: {', '.join(VARIANTS)}")

    config = str(args.full / "config.json") if args.full else args.config
    sets = [*args.sets, f"data.cache_dir={args.out / 'cache'}"]  # proposals are shared by all variants
    run_dirs = {name: args.out / name for name in VARIANTS if VARIANTS[name][0] is not None}
    if args.full:
        run_dirs["full"] = args.full
    to_train = [n for n in chosen if VARIANTS[n][0] is not None and not (args.full and n == "full")]
    seconds = train_all(args, config, sets, to_train, run_dirs)

    path = args.out / "ablation.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for name in chosen:
        train_sets, infer_sets = VARIANTS[name]
        run_dir = run_dirs["full" if train_sets is None else name]
        report = args.out / f"eval-{name}" / "eval" / "eval.json"
        if args.reuse and report.exists():
            scores = scores_of(json.loads(report.read_text()))
        else:
            scores = detect_and_score(run_dir / "checkpoint.pt", args.test_dir, args.out / f"eval-{name}",
                                      infer_sets, args.device or "cpu")  # fmt: skip
        results[name] = {"map25": scores["map25_all"], "map25_present": scores["map25_present"],
                         "paper_map25": PAPER_MAP.get(name, float("nan")), "train_seconds": seconds.get(name),
                         "run": str(run_dir), "test_frames": scores["test_frames"]}  # fmt: skip
        path.write_text(json.dumps(results, indent=1))

    scored = {n: args.out / f"eval-{n}" / "detections.jsonl" for n in results}
    maps = {}
    if args.bootstrap and "full" in scored:
        maps = bootstrap_maps(args.test_dir, scored, args.bootstrap)
    for name in maps.keys() - {"full"}:
        results[name]["full_minus_variant_90"] = interval_90(maps["full"] - maps[name])
    path.write_text(json.dumps(results, indent=1))

    print(f"{'variant':<12} {'mAP@0.25':>9} {'present':>8} {'paper':>6}  full - variant, 90 % interval")
    for name, r in results.items():
        interval = r.get("full_minus_variant_90")
        shown = f"  [{interval[0]:+.1f}, {interval[1]:+.1f}]" if interval else ""
        scores = f"{100 * r['map25']:9.1f} {100 * r['map25_present']:8.1f} {r['paper_map25']:6.1f}"
        print(f"{name:<12} {scores}{shown}")
    if args.per_class:
        print_per_class(args.out, [n for n in results if n in PAPER_AP])
    if set(PAPER_MAP) <= results.keys():
        print_ordering(results, maps)
    return 0


def print_per_class(out: Path, names: list[str]) -> None:
    """AP@0.25 per class of each Table 2 variant, ours / the paper's (OUT/eval-VARIANT's eval.json)."""
    ap = {n: json.loads((out / f"eval-{n}" / "eval" / "eval.json").read_text())["classes"] for n in names}
    print(f"{'class':<13}" + "".join(f" {n:>13}" for n in names) + "   (ours / paper)")
    for c, cls in enumerate(CLASSES):
        cells = [f"{100 * ap[n][cls]['ap']['0.25']:5.1f} / {PAPER_AP[n][c]:5.1f}" for n in names]
        print(f"{cls:<13}" + "".join(f" {cell:>13}" for cell in cells))


def print_ordering(results: dict, maps: dict[str, np.ndarray]) -> None:
    """The paper's three conclusions from Table 2 as differences of its steps "img" -> "img+d"
    (depth), "img+d" -> "img+d+ct" (context) and initial boxes -> "img+d+ct" (3D regression), in
    mAP@0.25 points, with paired 90 % intervals when bootstrapped: 3D regression is the largest
    gain, colour + depth beats colour only, context does not hurt."""
    checks = {  # label: ({variant: coefficient}, "no harm": need only not be significantly negative)
        "3D regression gain - depth gain": ({"full": 1, "no-3dreg": -1, "no-context": -1, "color": 1}, False),
        "3D regression gain - context gain": ({"no-context": 1, "no-3dreg": -1}, False),
        "depth gain (colour + depth - colour)": ({"no-context": 1, "color": -1}, False),
        "context gain": ({"full": 1, "no-context": -1}, True),
    }
    print("the paper's ordering, in points: ours (paper's), paired 90 % interval")
    for label, (terms, no_harm) in checks.items():
        diff = sum(k * 100 * results[v]["map25"] for v, k in terms.items())
        paper = sum(k * PAPER_MAP[v] for v, k in terms.items())
        lo, hi = interval_90(sum(k * maps[v] for v, k in terms.items())) if maps else (diff, diff)
        shown = f"  [{lo:+.1f}, {hi:+.1f}]" if maps else ""
        if no_harm:
            verdict = "holds" if hi >= 0 else "fails"
        else:
            verdict = "holds, significant" if lo > 0 else "holds" if diff > 0 else "fails"
        print(f"  {label:<37} {diff:+6.1f} ({paper:+5.1f}){shown}  {verdict}")


def train_all(args: argparse.Namespace, config: str, sets: list[str], names: list[str],
              run_dirs: dict[str, Path]) -> dict[str, float]:  # fmt: skip
    """a3d-train each variant, up to --parallel at once; wall seconds per variant."""
    threads = max(1, (os.cpu_count() or 1) // max(1, args.parallel))
    extra = [f"solver.threads={threads}", "data.workers=0"] if args.parallel > 1 else []
    pending, running, seconds = list(names), {}, {}
    while pending or running:
        while pending and len(running) < max(1, args.parallel):
            name = pending.pop(0)
            run_dir = run_dirs[name]
            command = [str(BIN / "a3d-train"), str(args.train_dir), "--out", str(run_dir)]
            resume = (run_dir / "checkpoint.pt").exists()
            command += ["--resume"] if resume else ["--config", config]
            for s in (*sets, *VARIANTS[name][0], *extra):
                command += ["--set", s]
            if args.iters:
                command += ["--iters", str(args.iters)]
            if args.device:
                command += ["--device", args.device]
            print("$", " ".join(command), flush=True)
            args.out.mkdir(parents=True, exist_ok=True)
            log = open(args.out / f"train-{name}.log", "a", encoding="utf-8")  # closed when the run ends
            proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
            running[name] = (proc, log, time.time())
        time.sleep(2)
        for name, (proc, log, start) in list(running.items()):
            if proc.poll() is not None:
                log.close()
                del running[name]
                if proc.returncode != 0:
                    sys.exit(f"training {name} failed ({proc.returncode}); see {args.out}/train-{name}.log")
                seconds[name] = time.time() - start
    return seconds


if __name__ == "__main__":
    sys.exit(main())
