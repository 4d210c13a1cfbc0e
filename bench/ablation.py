"""The paper's ablation (Table 2) on a data set: what depth, context and 3D regression contribute.

    .venv/bin/python bench/ablation.py TRAIN_DIR TEST_DIR --out out/ablation [--config cpu-small]
        [--iters N] [--set KEY=VALUE ...] [--only full,color,no-context,no-3dreg]

Variants (all with the same configuration otherwise, each trained from scratch into OUT/VARIANT):
  full        colour + depth + context + 3D regression          (paper: 40.9)
  color       colour only, one trunk (net.use_depth=false)       (paper: "img" 30.0)
  no-context  colour + depth without the context box            (paper: "img+d" 40.1)
  no-3dreg    the full model's detections with their initial boxes, i.e. no 3D regression
              (inference.regress_3d=false; no training)           (paper: 15.5)
Each is scored with a3d-eval at 3D IoU 0.25 (mAP over the 19 classes) on TEST_DIR, through the
torch reference path. Prints the table and writes OUT/ablation.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from train_synth import detect_and_score, train  # bench/ is the script's folder, first on sys.path

VARIANTS = {
    "full": ([], [], 40.9),
    "color": (["net.use_depth=false"], [], 30.0),
    "no-context": (["net.use_context=false"], [], 40.1),
    "no-3dreg": (None, ["inference.regress_3d=false"], 15.5),  # None: the full model's checkpoint
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("train_dir", type=Path)
    parser.add_argument("test_dir", type=Path)
    parser.add_argument("--out", type=Path, default=Path("out/ablation"))
    parser.add_argument("--config", default="cpu-small")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--iters", type=int)
    parser.add_argument("--only", default=",".join(VARIANTS), help="comma-separated variants")
    parser.add_argument("--device")
    args = parser.parse_args()
    chosen = args.only.split(",")
    unknown = sorted(set(chosen) - set(VARIANTS))
    if unknown:
        parser.error(f"unknown variants {unknown}; known: {', '.join(VARIANTS)}")

    sets = [*args.sets, f"data.cache_dir={args.out / 'cache'}"]  # proposals are shared by all variants
    results = {}
    for name in chosen:
        train_sets, infer_sets, paper = VARIANTS[name]
        run_dir = args.out / ("full" if train_sets is None else name)
        seconds = None
        if not (run_dir / "checkpoint.pt").exists():
            seconds = train(args.train_dir, run_dir, args.config, sets + (train_sets or []), args.iters, None,
                            False, args.device)  # fmt: skip
        scores = detect_and_score(run_dir / "checkpoint.pt", args.test_dir, args.out / f"eval-{name}",
                                  infer_sets, args.device or "cpu")  # fmt: skip
        results[name] = {"map25": scores["map25_all"], "map25_present": scores["map25_present"],
                         "paper_map25": paper, "train_seconds": seconds}  # fmt: skip
        (args.out / "ablation.json").write_text(json.dumps(results, indent=1))

    print(f"{'variant':<12} {'mAP@0.25':>9} {'present':>8} {'paper':>6}")
    for name, r in results.items():
        print(f"{name:<12} {100 * r['map25']:9.1f} {100 * r['map25_present']:8.1f} {r['paper_map25']:6.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
