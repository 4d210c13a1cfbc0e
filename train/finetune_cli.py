"""a3d-finetune: a model fine-tuned on your own labelled recordings in minutes on the CPU.

    a3d-finetune FOLDER... --out model.onnx [--base NAME|FILE] [--minutes 15] [--holdout 0.2]
                 [--synth FOLDER | --synth-frames N] [--work DIR] [--set KEY=VALUE ...]

Each FOLDER is one recording as an annotated frame folder (a3d-labels writes one from boxes drawn
once: docs/mapping.md). The last HOLDOUT of each recording's frames is held back; the rest is mixed
with synthetic frames of the bundled model's world and fine-tunes the base model (bundled by name,
or a model file; by default the bundled pipeline's network) for the recipe's iterations or what the
budget leaves, whichever is less; a pipeline's 2D detector is left as it is and named in the new
model, which runs with it. The result is exported int8, its scores calibrated on the held-back
frames, and its card (base model, data, recipe, mAP@0.25 on the held-back frames before and after)
written into its metadata (a3d-run --model-info shows it). Ctrl-C stops the training and exports
what it has. Bad input (a folder without ground truth, a class outside the 19, a budget too short
to train) is one line and exit 2, with nothing written.
docs/training.md "Your own room" has the steps and a measured run.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.extras import Needs
from a3d.runtime.models import DEFAULT_MODEL

PROG = "a3d-finetune"
NEEDS = Needs("train", ("torch", "onnx", "onnxscript", "matplotlib"))


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0], needs=NEEDS)
    p.add_argument(
        "folders", type=Path, nargs="+", metavar="FOLDER", help="annotated recordings, one a folder"
    )
    p.add_argument("--out", type=Path, required=True, help="the fine-tuned model file to write (model.onnx)")
    p.add_argument("--base", default=DEFAULT_MODEL,
                   help="the model to start from: a bundled model's name or a file; a pipeline's 2D "
                   "detector is kept (the new model names it) and its network fine-tuned")  # fmt: skip
    p.add_argument("--minutes", type=float, default=15.0, help="wall-clock budget of the whole command")
    p.add_argument("--holdout", type=float, default=0.2, help="share of each recording held back at its end")
    synth = p.add_mutually_exclusive_group()
    synth.add_argument("--synth", type=Path, metavar="FOLDER", help="annotated synthetic frames to mix in")
    synth.add_argument(
        "--synth-frames", type=int, metavar="N",
        help="a3d-synth frames to mix in (default: as many as yours, at least 40)",
    )  # fmt: skip
    p.add_argument("--work", type=Path, help="working folder: split, caches, run (default: OUT.finetune)")
    p.add_argument("--iters", type=int, help="the most iterations to run (default: the recipe's, "
                   "docs/training.md \"Your own room\"; fewer where the budget holds fewer)")
    p.add_argument("--lr", type=float, default=0.0001, help="learning rate (x0.1 for the last fifth)")
    p.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads and a3d-synth workers")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a training setting over the recipe's, as a3d-train takes it, e.g. "
                   "data.detector_rois=2 (repeatable)")  # fmt: skip
    return p


@command(PROG, errors=(ValueError, FileNotFoundError))
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not 0 < args.holdout < 1:
        parser.error(f"--holdout must be a share in (0, 1), got {args.holdout:g}")
    iters_ok = args.iters is None or args.iters >= 1
    if not args.minutes > 0 or not iters_ok or args.threads < 1 or not args.lr > 0:
        parser.error("--minutes, --iters, --threads and --lr must be positive")
    if args.synth_frames is not None and args.synth_frames < 1:
        parser.error("--synth-frames must be >= 1")
    from a3d.train.finetune import Recipe, finetune  # torch, after the flags (NEEDS)

    handler = logging.StreamHandler()  # a3d's own messages (the training plan), not the exporter's
    handler.setFormatter(logging.Formatter(f"{PROG}: %(message)s"))
    root = logging.getLogger("a3d")
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    try:
        recipe = Recipe(lr=args.lr) if args.iters is None else Recipe(lr=args.lr, iterations=args.iters)
        path = finetune(args, recipe)
    finally:  # a caller in the same process (the tests) keeps its own logging
        root.removeHandler(handler)
        root.setLevel(level)
    print(f"{PROG}: wrote {path}; run it with:", file=sys.stderr)
    print(f"a3d-run FRAMES --model {path} --output detections.jsonl --headless")
    return 0


if __name__ == "__main__":
    sys.exit(main())
