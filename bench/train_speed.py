"""a3d-train's SGD step alone, in the memory formats and precisions it could use on this CPU.

    .venv/bin/python -m bench.train_speed [--config cpu-small] [--size 240x320] [--threads 2]

One mini-batch of random colour, depth, RoIs and targets at the network's input size (the
default: a 480 x 640 frame at cpu-small's input scale 0.5), ``data.images_per_batch`` images of
``data.rois_per_image`` RoIs, through a3d-train's own forward and loss (``forward_loss``), backward
and SGD step, timed per variant: fp32 with contiguous convolutions (what a3d-train did before),
fp32 channels-last (what it does now) and bf16 autocast channels-last (``solver.precision=bf16``).
The data loader is not timed: a run's iterations per second sit below these. The CPU's native
bfloat16 instructions are printed first; without them bf16 is emulated and slower.
"""

from __future__ import annotations

import argparse
import time

import torch

from a3d.runtime.network.cpu_support import bf16_instructions, int8_dot_products
from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.train.config import load_config
from a3d.train.loop import forward_loss
from a3d.train.model import A3DNet
from bench.model_speed import random_rois

VARIANTS = {  # name -> (channels-last, bf16)
    "fp32 contiguous": (False, False),
    "fp32 channels-last": (True, False),
    "bf16 channels-last": (True, True),
}


def random_batch(images: int, rois_per_image: int, height: int, width: int, seed: int = 0) -> dict:
    """A mini-batch in a3d-train's layout (random_rois' boxes), a quarter of the RoIs foreground."""
    g = torch.Generator().manual_seed(seed)
    n = images * rois_per_image
    rois, context = random_rois(n, images, height, width, g)
    labels = torch.randint(1, NUM_OUTPUTS, (n,), generator=g) * (torch.rand(n, generator=g) < 0.25)
    return {
        "color": torch.randn(images, 3, height, width, generator=g),
        "depth": torch.randn(images, 3, height, width, generator=g),
        "rois": rois,
        "context_rois": context,
        "labels": labels,
        "targets3d": torch.randn(n, BOX_DIM, generator=g),
        "targets2d": torch.randn(n, 4, generator=g),
        "weights3d": torch.ones(n),
    }


def steps_per_second(config, batch: dict, channels_last: bool, bf16: bool, warmup: int, steps: int) -> float:
    torch.manual_seed(0)
    net = A3DNet(config.net).train()
    if channels_last:
        net = net.to(memory_format=torch.channels_last)
    optimizer = torch.optim.SGD(net.parameters(), lr=1e-4, momentum=0.9)
    for i in range(warmup + steps):
        if i == warmup:
            start = time.perf_counter()
        loss = forward_loss(net, batch, config.solver, bf16).total
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    return steps / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.train_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="cpu-small", help="a3d-train preset or config file")
    parser.add_argument("--size", default="240x320", help="network input H x W (after data.input_scale)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--steps", type=int, default=15)
    args = parser.parse_args(argv)
    height, width = (int(v) for v in args.size.split("x"))
    torch.set_num_threads(args.threads)
    config = load_config(args.config)
    native, dot = ", ".join(bf16_instructions()), ", ".join(int8_dot_products())
    print(f"CPU: native bfloat16 {native or 'none (emulated)'}; int8 dot products {dot or 'none'}; "
          f"{args.threads} threads")  # fmt: skip
    batch = random_batch(config.data.images_per_batch, config.data.rois_per_image, height, width)
    print(f"{args.config}, {config.data.images_per_batch} images of {height} x {width}, "
          f"{config.data.rois_per_image} RoIs each: SGD steps per second")  # fmt: skip
    base = None
    for name, (channels_last, bf16) in VARIANTS.items():
        rate = steps_per_second(config, batch, channels_last, bf16, args.warmup, args.steps)
        base = base or rate
        print(f"  {name:<20} {rate:6.2f}  ({rate / base:.2f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
