"""``a3d-pretrain DATA --out WEIGHTS.pt``: colour-crop pretraining of the trunk (a3d.train.pretrain).

    a3d-synth data/pretrain --frames 2000 --seed 99 --appearance typical
    a3d-pretrain data/pretrain --out weights/synth-vgg16.pt --config cpu-small
    a3d-train data/train --out runs/small --config cpu-small --set solver.pretrained=weights/synth-vgg16.pt

The trunk's shape (net.width, net.trunk_norm, fc6, fc7, dropout) comes from ``--config`` and
``--set net.*`` as for a3d-train; the schedule from the flags. Writes WEIGHTS.pt (torchvision's
VGG16 key layout) and WEIGHTS.pt.json (validation accuracy, settings).
Bad input is reported as one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.extras import Needs
from a3d.train.cli import add_config_arguments, config_source
from a3d.train.config import PretrainConfig, load_config

PROG = "a3d-pretrain"
NEEDS = Needs("train", ("torch",))  # checked after parsing: --help works without torch


def build_parser() -> argparse.ArgumentParser:
    defaults = PretrainConfig()
    about = "Pretrain the VGG16 trunk on colour crops (a stand-in for ImageNet)."
    parser = command_parser(PROG, about, needs=NEEDS)
    parser.add_argument("data", type=Path, help="folder of annotated frames, disjoint from the detector's")
    parser.add_argument("--out", type=Path, required=True, help="weights file to write (.pt)")
    add_config_arguments(parser, "net.width=0.5")
    parser.add_argument("--iters", type=int, default=defaults.iterations, help="SGD iterations")
    parser.add_argument("--batch", type=int, default=defaults.batch, help="crops per iteration")
    parser.add_argument("--lr", type=float, default=defaults.lr, help="learning rate (x0.1 after 3/4)")
    parser.add_argument("--crop", type=int, default=defaults.crop, help="crop side (px); 16 x net.pool_size")
    parser.add_argument("--val-share", type=float, default=defaults.val_share, help="frames held out")
    parser.add_argument("--seed", type=int, default=defaults.seed, help="seed: split, crops, weights")
    parser.add_argument("--threads", type=int, default=0, help="torch threads, 0: as many as torch picks")
    return parser


@command(PROG, errors=(ValueError, FileNotFoundError))
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.iters < 1 or args.batch < 1 or not 0 <= args.val_share < 1:
        parser.error("--iters and --batch must be positive and --val-share in [0, 1)")
    import torch

    from a3d.train.loop import resolve_device
    from a3d.train.pretrain import pretrain

    net = load_config(config_source(args, PROG), args.overrides).net
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    schedule = PretrainConfig(iterations=args.iters, batch=args.batch, lr=args.lr, crop=args.crop,
                              val_share=args.val_share, seed=args.seed)  # fmt: skip
    result = pretrain(args.data, args.out, net, schedule, device=str(resolve_device(args.device)))
    held_out = "no held-out crops"
    if result.val_crops:
        held_out = (f"held-out accuracy {100 * result.val_accuracy:.1f} % (balanced "
                    f"{100 * result.val_balanced_accuracy:.1f} %, {result.val_crops} crops)")  # fmt: skip
    print(
        f"{PROG}: {result.iterations} iterations on {result.train_crops} crops -> {args.out}; "
        f"training-crop accuracy {100 * result.train_accuracy:.1f} %, {held_out}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
