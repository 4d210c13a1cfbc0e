"""``a3d-train DATA --out RUN_DIR``: train A3DNet on a folder of annotated RGB-D frames.

    a3d-train data/train --out runs/small --config cpu-small --val data/test
    a3d-train data/train --out runs/small --resume --iters 6000     # continue (after Ctrl-C too), or extend
    a3d-train data/train --out runs/hour --config cpu-small --minutes 55 --iters 40000  # fit to 55 minutes
    a3d-train mine/train data/train --out runs/mine --set solver.init=runs/small/checkpoint.pt  # two folders
    torchrun --nproc_per_node 2 -m a3d.train.cli data/train --out runs/ddp --config cpu-small

``--config`` is a preset name (a3d.train.config.PRESETS: vgg16, cpu-small, cpu-tiny, and every
network preset of a3d.train.model such as vgg16-fused) or a JSON/TOML file (without it:
vgg16 on a CUDA device, cpu-small otherwise, said on stderr); ``--set a.b=v``
overrides single settings (``--set solver.lr=0.001 --set data.workers=2``). With ``--resume``
the configuration comes from the run's checkpoint; ``--set`` and ``--iters`` still apply on top
(changing anything but the schedule's length breaks bit-exact resumption).
Writes RUN_DIR/checkpoint.pt, metrics.jsonl, loss.png and config.json, and prints the
a3d-export command for the run.
Bad input is reported as one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.extras import Needs
from a3d.train.config import CPU_PRESET, GPU_PRESET, PRESETS, TrainConfig, apply_overrides, load_config

PROG = "a3d-train"
NEEDS = Needs("train", ("torch", "matplotlib"))  # checked after parsing: --help works without torch


def build_parser() -> argparse.ArgumentParser:
    about = "Train the amodal 3D detector (Deng & Latecki 2017) on RGB-D frames."
    parser = command_parser(PROG, about, needs=NEEDS)
    parser.add_argument("data", type=Path, nargs="+",
                        help="folders of training frames with NAME.gt.json (one or more)")  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, help="run folder (checkpoint, metrics, plots)")
    add_config_arguments(parser, "solver.lr=0.001")
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument("--resume", action="store_true", help="continue the run in --out")
    existing.add_argument("--force", action="store_true", help="start again over the run in --out")
    parser.add_argument("--iters", type=int, help="total iterations (default: the preset's)")
    parser.add_argument("--minutes", type=float, help="fit the run to this wall-clock budget on this machine "
                        "(--iters is then the most it runs; the lr steps scale with it)")  # fmt: skip
    parser.add_argument("--val", type=Path, help="annotated frames to validate on (default: none)")
    return parser


def add_config_arguments(parser: argparse.ArgumentParser, example: str) -> None:
    """--config, --set (into ``overrides``) and --device, as a3d-train and a3d-pretrain take them."""
    parser.add_argument("--config", help=f"preset ({', '.join(PRESETS)}) or JSON/TOML file "
                        f"(default: {GPU_PRESET} on CUDA, else {CPU_PRESET})")  # fmt: skip
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help=f"override one setting, e.g. {example} (repeatable)")  # fmt: skip
    parser.add_argument("--device", help="cpu, cuda or cuda:N (default: cuda when available)")


def config_source(args: argparse.Namespace, prog: str = PROG) -> str:
    """--config, or the preset that fits the device (the paper's network needs a GPU), said on stderr."""
    if args.config:
        return args.config
    from a3d.train.loop import resolve_device  # torch

    device = resolve_device(args.device)
    preset = GPU_PRESET if device.type == "cuda" else CPU_PRESET
    why = "a CUDA device" if device.type == "cuda" else "no CUDA device"
    print(f"{prog}: no --config: preset {preset} ({why}; --config picks another)", file=sys.stderr)
    return preset


def resolve_config(args: argparse.Namespace) -> TrainConfig:
    """Preset/file + overrides, or, with --resume, the checkpoint's config + overrides."""
    from a3d.train.checkpoint import checkpoint_config  # torch
    from a3d.train.loop import CHECKPOINT_NAME

    if args.resume:
        if args.config:
            raise ValueError("--resume takes the configuration from the checkpoint; drop --config")
        config = apply_overrides(checkpoint_config(args.out / CHECKPOINT_NAME), args.overrides)
    else:
        config = load_config(config_source(args), args.overrides)
    if args.iters is not None:
        if args.iters < 1:
            raise ValueError(f"--iters must be positive, got {args.iters}")
        config = apply_overrides(config, [f"solver.iterations={args.iters}"])
    if args.minutes is not None:
        if not args.minutes > 0:
            raise ValueError(f"--minutes must be positive, got {args.minutes}")
        config = apply_overrides(config, [f"solver.minutes={args.minutes}"])
    return config


@command(PROG, errors=(ValueError, FileNotFoundError))
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from a3d.train.loop import train  # torch, after the flags (NEEDS)

    logging.basicConfig(level=logging.INFO, format=f"{PROG}: %(message)s")
    config = resolve_config(args)
    result = train(args.data, args.out, config, device=args.device, resume=args.resume, overwrite=args.force,
                   val_data=args.val)  # fmt: skip
    summary = f"{PROG}: {result.iteration} iterations in {result.run_dir}"
    if result.last_loss is not None:
        summary += f", last loss {result.last_loss:.4f}"
    if result.val_map is not None:
        summary += f", val mAP@0.25 {100 * result.val_map:.1f}"
    print(summary, file=sys.stderr)
    print(f"{PROG}: export the model with:", file=sys.stderr)
    print(export_command(result.run_dir, args.val))
    return 0


def export_command(run_dir: Path, val: Path | None) -> str:
    """The a3d-export command line that turns this run's checkpoint into RUN_DIR/model.onnx."""
    from a3d.train.loop import CHECKPOINT_NAME

    words = ["a3d-export", str(run_dir / CHECKPOINT_NAME), "-o", str(run_dir / "model.onnx")]
    if val is not None:
        words += ["--verify-frames", str(val)]
    return shlex.join(words)


if __name__ == "__main__":
    sys.exit(main())
