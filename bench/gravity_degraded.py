"""Gravity on depth degraded as real sensors degrade it: error per degradation and fallback counts.

a3d-synth frames of held-out seeds are rendered in memory (a3d.synth.scene.generate_frame, with
its Kinect-like sensor model) and their depth is degraded four ways, each with its own seeded
generator so that every run sees the same frames:

- ``random 90%``: 90 % of the valid depth pixels removed at random (a sparse sensor);
- ``50k points``: the depth back-projected to a point cloud, 50 000 points kept at random and
  projected back (the nearest point wins a pixel), as a subsampled cloud saved by another tool;
- ``flying pixels``: Kinect v2-style mixed pixels: within 2 pixels of a depth edge (a relative
  step over 5 %), depth takes a random value between the near and the far surface;
- ``blobs 30%``: 30 % of the valid pixels missing in large blobs (thresholded smooth noise,
  sigma 25 pixels), like dark or shiny surfaces.

For each, the angle between the estimated and the true gravity (row 1 of the frame's R_tilt) is
reported for the runtime's choice (a3d.runtime.frontend.gravity.choose_gravity: raw depth, then
the documented fallbacks; targets median <= 2 and p95 <= 5 degrees) and, to show what works,
for the estimate on the raw depth alone, on the hole-filled depth alone and on a valid-weighted
4x down-sampled depth alone (normals at every pixel of it); then the count of frames per gravity source.

    .venv/bin/python -m bench.gravity_degraded [--first 900000] [--count 40]
"""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Callable

import cv2
import numpy as np

from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.gravity import GravityConfig, choose_gravity, estimate_gravity
from a3d.runtime.frontend.normals import NormalConfig
from a3d.runtime.structures.geometry import Intrinsics, backproject_depth, project_points

Degrade = Callable[[np.ndarray, Intrinsics, np.random.Generator], np.ndarray]


def drop_random(
    depth: np.ndarray, K: Intrinsics, rng: np.random.Generator, fraction: float = 0.9
) -> np.ndarray:
    """``fraction`` of the valid pixels set to 0, at random."""
    out = depth.copy()
    valid = np.flatnonzero(out > 0)
    out.flat[rng.choice(valid, int(fraction * len(valid)), replace=False)] = 0
    return out


def keep_points(depth: np.ndarray, K: Intrinsics, rng: np.random.Generator, n: int = 50_000) -> np.ndarray:
    """The depth as a point cloud, ``n`` points kept at random, projected back (nearest wins)."""
    points = backproject_depth(depth, K)[depth > 0]
    points = points[rng.choice(len(points), min(n, len(points)), replace=False)]
    uv = np.round(project_points(points, K)).astype(np.int64)
    h, w = depth.shape
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    uv, z = uv[inside], points[inside, 2]
    order = np.argsort(-z)  # far first, so that the nearest point of a pixel is written last
    out = np.zeros_like(depth)
    out[uv[order, 1], uv[order, 0]] = z[order]
    return out


def flying_pixels(
    depth: np.ndarray, K: Intrinsics, rng: np.random.Generator, width: int = 2, step: float = 0.05
) -> np.ndarray:
    """Pixels within ``width`` of a relative depth step > ``step`` take a random depth between
    the near and the far surface of their neighbourhood (mixed-pixel returns)."""
    kernel = np.ones((2 * width + 1, 2 * width + 1), np.uint8)
    far = cv2.dilate(depth, kernel)
    near = cv2.erode(np.where(depth > 0, depth, np.inf).astype(np.float32), kernel)
    edge = (depth > 0) & np.isfinite(near) & (far - near > step * near)
    out = depth.copy()
    out[edge] = near[edge] + rng.random(int(edge.sum()), dtype=np.float32) * (far[edge] - near[edge])
    return out


def drop_blobs(
    depth: np.ndarray, K: Intrinsics, rng: np.random.Generator, fraction: float = 0.3, sigma: float = 25.0
) -> np.ndarray:
    """``fraction`` of the valid pixels set to 0 in large blobs (smooth noise below its quantile)."""
    noise = cv2.GaussianBlur(rng.standard_normal(depth.shape).astype(np.float32), (0, 0), sigma)
    valid = depth > 0
    out = depth.copy()
    out[valid & (noise < np.quantile(noise[valid], fraction))] = 0
    return out


DEGRADATIONS: dict[str, Degrade] = {
    "clean": lambda depth, K, rng: depth,
    "random 90%": drop_random,
    "50k points": keep_points,
    "flying pixels": flying_pixels,
    "blobs 30%": drop_blobs,
}


def downsampled(depth: np.ndarray, K: Intrinsics, factor: int = 4) -> tuple[np.ndarray, Intrinsics]:
    """Valid-weighted block means of ``factor`` x ``factor`` blocks, and the matching intrinsics."""
    h, w = (depth.shape[0] // factor) * factor, (depth.shape[1] // factor) * factor
    blocks = depth[:h, :w].reshape(h // factor, factor, w // factor, factor)
    count = (blocks > 0).sum(axis=(1, 3))
    mean = np.where(count > 0, blocks.sum(axis=(1, 3)) / np.maximum(count, 1), 0).astype(np.float32)
    # block (i, j) covers pixels factor*j .. factor*j + factor - 1: its centre is at factor*j + (factor-1)/2
    shift = (factor - 1) / 2
    small = Intrinsics(K.fx / factor, K.fy / factor, (K.cx - shift) / factor, (K.cy - shift) / factor)
    return mean, small


# On the 4x smaller map every pixel is a normal sample (the default samples every 4th pixel).
DOWNSAMPLED_CONFIG = GravityConfig(normals=NormalConfig(step=1))


def angle_deg(g: np.ndarray, R_tilt: np.ndarray) -> float:
    """Angle between a camera-frame down vector and an R_tilt's (its row 1)."""
    g = np.asarray(g, np.float64) / np.linalg.norm(g)
    return float(np.degrees(np.arccos(np.clip(g @ R_tilt[1], -1.0, 1.0))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, default=900_000, help="first seed (held out of training)")
    parser.add_argument("--count", type=int, default=40, help="frames")
    args = parser.parse_args()
    from a3d.synth.scene import generate_frame

    methods = ("runtime", "raw only", "filled only", "down-sampled only")
    errors = {name: {m: [] for m in methods} for name in DEGRADATIONS}
    sources: dict[str, Counter[str]] = {name: Counter() for name in DEGRADATIONS}
    for seed in range(args.first, args.first + args.count):
        frame = generate_frame(seed)
        K, truth = frame.intrinsics, frame.R_tilt
        for d, (name, degrade) in enumerate(DEGRADATIONS.items()):
            depth = degrade(frame.depth, K, np.random.default_rng([seed, d]))
            filled = fill_depth(depth)
            choice = choose_gravity(depth, filled, K)
            sources[name][choice.source.split(" (")[0]] += 1
            small, K_small = downsampled(depth, K)
            row = errors[name]
            row["runtime"].append(angle_deg(choice.R_tilt[1], truth))
            row["raw only"].append(angle_deg(estimate_gravity(depth, K).gravity, truth))
            row["filled only"].append(angle_deg(estimate_gravity(filled, K).gravity, truth))
            coarse = estimate_gravity(small, K_small, DOWNSAMPLED_CONFIG)
            row["down-sampled only"].append(angle_deg(coarse.gravity, truth))

    print(f"{args.count} a3d-synth frames, seeds {args.first}..{args.first + args.count - 1}")
    print("gravity angle error, degrees: median / p95 / max (targets for the runtime: <= 2 / <= 5)")
    print(f"{'degradation':14s}" + "".join(f"{m:>22s}" for m in methods))
    for name, row in errors.items():
        cells = [np.asarray(row[m]) for m in methods]
        print(
            f"{name:14s}"
            + "".join(f"{np.median(e):8.2f}{np.percentile(e, 95):7.2f}{e.max():7.2f}" for e in cells)
        )
    print("gravity source per frame (the runtime's choice; every fallback is also warned on stderr):")
    for name, counts in sources.items():
        print(f"{name:14s} " + ", ".join(f"{source}: {n}" for source, n in sorted(counts.items())))


if __name__ == "__main__":
    main()
