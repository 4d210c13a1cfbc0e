"""``a3d-average RUN_A/checkpoint.pt RUN_B/checkpoint.pt ... --out SOUP.pt``: average fine-tuned runs.

    a3d-train data/a --out runs/a --set solver.init=runs/base/checkpoint.pt --set solver.seed=1
    a3d-train data/b --out runs/b --set solver.init=runs/base/checkpoint.pt --set solver.seed=2
    a3d-average runs/a/checkpoint.pt runs/b/checkpoint.pt --out runs/soup.pt
    a3d-export runs/soup.pt -o model.onnx

The runs must share the network and the regression targets that solver.init carries over
(a3d.train.average). Writes SOUP.pt atomically, without optimizer state.
Bad input is reported as one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.extras import Needs

PROG = "a3d-average"
NEEDS = Needs("train", ("torch",))  # checked after parsing: --help works without torch


def build_parser() -> argparse.ArgumentParser:
    about = "Average the weights of runs fine-tuned from one checkpoint (a model soup)."
    parser = command_parser(PROG, about, needs=NEEDS)
    parser.add_argument("checkpoints", type=Path, nargs="+", help="a3d-train checkpoints, two or more")
    parser.add_argument("--out", type=Path, required=True, help="checkpoint to write (.pt)")
    return parser


@command(PROG, errors=(ValueError, FileNotFoundError))
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.out.resolve() in {p.resolve() for p in args.checkpoints}:
        parser.error(f"--out {args.out} is one of the checkpoints to average")
    from a3d.train.average import average_checkpoints  # torch
    from a3d.train.checkpoint import save_checkpoint

    save_checkpoint(args.out, average_checkpoints(args.checkpoints))
    print(f"{PROG}: {len(args.checkpoints)} checkpoints averaged into {args.out}", file=sys.stderr)
    return 0
