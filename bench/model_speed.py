"""A3DNet size and CPU speed per preset: parameters, training step and forward time.

Training step: forward + backward (softmax loss + smooth-L1 on random targets) on a mini-batch of
2 images at 427 x 561 and 256 RoIs (docs/conventions.md "Training"); no optimiser update. Forward: eval mode,
one image, trunk and head timed separately, for each RoI count. Random weights and boxes. The
fp32 GEMM rate printed before and after tells how busy the (shared) machine was.

    .venv/bin/python -m bench.model_speed --presets vgg16 --iterations 2 --forward-rois 300
    .venv/bin/python -m bench.model_speed --presets cpu-half cpu-quarter cpu-eighth
"""

from __future__ import annotations

import argparse
import time

import torch

from a3d.train.model.config import PRESETS, preset
from a3d.train.model.net import A3DNet


def random_rois(count: int, images: int, height: int, width: int, gen: torch.Generator):
    """(rois, context_rois), (count, 5) each, spread over the images; context = 1.5x, clipped."""
    size = torch.rand(count, 2, generator=gen) * torch.tensor([width / 2.0, height / 2.0]) + 16
    corner = torch.rand(count, 2, generator=gen) * (torch.tensor([width, height]) - size) - 0.5
    centre, half = corner + size / 2, size * 0.75
    low = torch.tensor([-0.5, -0.5])
    high = torch.tensor([width - 0.5, height - 0.5])
    context = torch.cat([torch.maximum(centre - half, low), torch.minimum(centre + half, high)], 1)
    index = (torch.arange(count) * images // count).float()[:, None]
    return torch.cat([index, corner, corner + size], 1), torch.cat([index, context], 1)


def timed(step, iterations: int) -> list[float]:
    seconds = []
    for _ in range(iterations):
        start = time.perf_counter()
        step()
        seconds.append(time.perf_counter() - start)
    return seconds


def gemm_gflops() -> float:
    """fp32 GEMM throughput right now: the yardstick for these timings on a shared machine."""
    a, b = torch.randn(1024, 2048), torch.randn(2048, 2048)
    a @ b
    seconds = min(timed(lambda: a @ b, 3))
    return 2 * 1024 * 2048 * 2048 / seconds / 1e9


def bench(name: str, args: argparse.Namespace) -> None:
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    net = A3DNet(preset(name))
    trunks = sum(p.numel() for n, p in net.named_parameters() if "trunk" in n)
    total = sum(p.numel() for p in net.parameters())
    head = total - trunks
    print(f"{name}: {total / 1e6:.2f} M parameters ({trunks / 1e6:.2f} M trunks, {head / 1e6:.2f} M head)")
    images = [torch.randn(2, 3, args.height, args.width, generator=gen) for _ in range(2)]
    rois, context = random_rois(args.rois, 2, args.height, args.width, gen)
    labels = torch.randint(0, 20, (args.rois,), generator=gen)
    targets = torch.randn(args.rois, 140, generator=gen)

    def train_step() -> None:
        net.zero_grad(set_to_none=True)
        logits, deltas3d, _ = net(*images, rois, context)
        loss = torch.nn.functional.cross_entropy(logits, labels)
        loss = loss + torch.nn.functional.smooth_l1_loss(deltas3d, targets)
        loss.backward()

    net.train()
    seconds = timed(train_step, args.iterations)
    print(f"  train step (2 images, {args.rois} RoIs): " + ", ".join(f"{s:.2f}" for s in seconds) + " s")
    net.zero_grad(set_to_none=True)
    net.eval()
    color, depth = (image[:1] for image in images)
    with torch.no_grad():
        trunk_seconds = timed(lambda: net.trunk_features(color, depth), args.iterations)
        features = net.trunk_features(color, depth)
        print("  forward trunks (1 image): " + ", ".join(f"{s:.3f}" for s in trunk_seconds) + " s")
        for count in args.forward_rois:
            boxes = random_rois(count, 1, args.height, args.width, gen)
            head_seconds = timed(lambda boxes=boxes: net.head(features, *boxes), args.iterations)
            print(f"  forward head ({count} RoIs): " + ", ".join(f"{s:.3f}" for s in head_seconds) + " s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), choices=list(PRESETS))
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--rois", type=int, default=256, help="RoIs per training mini-batch (2 images)")
    parser.add_argument("--forward-rois", type=int, nargs="*", default=[300, 2000])
    parser.add_argument("--height", type=int, default=427)
    parser.add_argument("--width", type=int, default=561)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {args.height} x {args.width}")
    print(f"fp32 GEMM now: {gemm_gflops():.0f} GFLOPS (docs/platform.md: 190-200 on an idle machine)")
    for name in args.presets:
        bench(name, args)
    print(f"fp32 GEMM now: {gemm_gflops():.0f} GFLOPS")


if __name__ == "__main__":
    main()
