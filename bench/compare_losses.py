"""Compare the per-iteration losses of two training runs (their ``metrics.jsonl``).

A refactoring that must not change training is checked by running the same short training
before and after it and comparing the curves:

    a3d-synth /tmp/th/data --frames 12 --seed 3 --split test=0.25
    a3d-train /tmp/th/data/train --out /tmp/th/before --config cpu-small --iters 30 --device cpu \
        --set data.workers=0 --set solver.threads=1 --set log.log_every=1 --set log.progress=false
    (change the code, then the same command with --out /tmp/th/after)
    python -m bench.compare_losses /tmp/th/before /tmp/th/after --tol 1e-5

Prints the largest absolute difference per loss term and exits 1 when it exceeds ``--tol`` or
the two runs logged different iterations.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

LOSS_KEYS = ("loss", "loss_cls", "loss_3d", "loss_2d")


def read_losses(run: Path) -> dict[int, dict[str, float]]:
    """iteration -> loss terms of every ``"kind": "train"`` line of RUN/metrics.jsonl (or the file itself)."""
    path = run / "metrics.jsonl" if run.is_dir() else run
    losses = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        record = json.loads(line)
        if record.get("kind") == "train":
            losses[int(record["iter"])] = {k: float(record[k]) for k in LOSS_KEYS}
    return losses


def max_differences(a: dict[int, dict[str, float]], b: dict[int, dict[str, float]]) -> dict[str, float]:
    """Largest absolute difference per loss term over the iterations both runs logged."""
    common = sorted(set(a) & set(b))
    return {k: max((abs(a[i][k] - b[i][k]) for i in common), default=0.0) for k in LOSS_KEYS}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path, help="run folder (or metrics.jsonl) of the reference run")
    parser.add_argument("after", type=Path, help="run folder (or metrics.jsonl) to compare")
    parser.add_argument("--tol", type=float, default=1e-5, help="largest allowed difference (default 1e-5)")
    args = parser.parse_args(argv)
    a, b = read_losses(args.before), read_losses(args.after)
    if not a or set(a) != set(b):
        print(f"iterations differ: {len(a)} logged in {args.before}, {len(b)} in {args.after}")
        return 1
    diffs = max_differences(a, b)
    print(f"{len(a)} iterations; max |difference|: " + ", ".join(f"{k} {v:.3g}" for k, v in diffs.items()))
    return 0 if max(diffs.values()) <= args.tol else 1


if __name__ == "__main__":
    sys.exit(main())
