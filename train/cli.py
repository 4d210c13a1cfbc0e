"""``a3d-train DATA --out RUN_DIR``: train A3DNet on a folder of annotated RGB-D frames.

    a3d-train data/train --out runs/small --config cpu-small --val data/test
    a3d-train data/train --out runs/small --resume --iters 6000     # continue, or extend
    torchrun --nproc_per_node 2 -m a3d.train.cli data/train --out runs/ddp --config cpu-small

``--config`` is a preset name (vgg16, cpu-small, ...) or a JSON/TOML file; ``--set a.b=v``
overrides single settings (``--set solver.lr=0.001 --set data.workers=2``). With ``--resume``
the configuration comes from the run's checkpoint; ``--set`` and ``--iters`` still apply on top
(changing anything but the schedule's length breaks bit-exact resumption).
Writes RUN_DIR/checkpoint.pt, metrics.jsonl, loss.png and config.json.
Bad input is reported as one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from a3d.runtime.errors import InputError, ModelError
from a3d.train.checkpoint import checkpoint_config
from a3d.train.config import PRESETS, TrainConfig, apply_overrides, load_config
from a3d.train.loop import CHECKPOINT_NAME, train


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="a3d-train", description="Train the amodal 3D detector (Deng & Latecki 2017) on RGB-D frames."
    )
    parser.add_argument("data", type=Path, help="folder of training frames with NAME.gt.json")
    parser.add_argument("--out", type=Path, required=True, help="run folder (checkpoint, metrics, plots)")
    add_config_arguments(parser, "solver.lr=0.001")
    parser.add_argument("--resume", action="store_true", help="continue from RUN_DIR/checkpoint.pt")
    parser.add_argument("--iters", type=int, help="total iterations (overrides solver.iterations)")
    parser.add_argument("--val", type=Path, help="annotated frames for periodic validation mAP")
    return parser


def add_config_arguments(parser: argparse.ArgumentParser, example: str) -> None:
    """--config, --set (into ``overrides``) and --device, as a3d-train and a3d-pretrain take them."""
    parser.add_argument("--config", help=f"preset ({', '.join(PRESETS)}) or JSON/TOML file; default vgg16")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help=f"override one setting, e.g. {example} (repeatable)")  # fmt: skip
    parser.add_argument("--device", help="cpu, cuda or cuda:N (default: cuda when available)")


def resolve_config(args: argparse.Namespace) -> TrainConfig:
    """Preset/file + overrides, or, with --resume, the checkpoint's config + overrides."""
    if args.resume:
        if args.config:
            raise ValueError("--resume takes the configuration from the checkpoint; drop --config")
        config = apply_overrides(checkpoint_config(args.out / CHECKPOINT_NAME), args.overrides)
    else:
        config = load_config(args.config, args.overrides)
    if args.iters is not None:
        if args.iters < 1:
            raise ValueError(f"--iters must be positive, got {args.iters}")
        config = apply_overrides(config, [f"solver.iterations={args.iters}"])
    return config


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="a3d-train: %(message)s")
    try:
        config = resolve_config(args)
        result = train(args.data, args.out, config, device=args.device, resume=args.resume, val_data=args.val)
    except (InputError, ModelError, ValueError, FileNotFoundError) as e:
        print(f"a3d-train: error: {e}", file=sys.stderr)
        return 2
    summary = f"a3d-train: {result.iteration} iterations in {result.run_dir}"
    if result.last_loss is not None:
        summary += f", last loss {result.last_loss:.4f}"
    if result.val_map is not None:
        summary += f", val mAP@0.25 {100 * result.val_map:.1f}"
    print(summary, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
