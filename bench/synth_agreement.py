"""Ground truth vs pixels over a whole synthetic set: the checks of a3d.synth.agreement.

Renders the frames ``a3d-synth --seed S --frames N`` would write (in memory, ``--workers``
processes) and reports, per depth band and overall: the annotated objects with any valid depth
(all are checked), how many have < 95 % of their valid-depth mask pixels in their 3D box + 5 cm,
and the worst share; frames whose exact depth leaves a box, whose amodal 2D box misses its
visible box, and the largest floor spread. Exits 1 when any of these fails.

    .venv/bin/python -m bench.synth_agreement --frames 1000 --seed 3 --workers 2 [--sensor kinect-v1]
"""

import argparse
import multiprocessing
import sys
from dataclasses import replace
from functools import partial

import cv2
import numpy as np
from tqdm import tqdm

from a3d.synth import SceneConfig, generate_frame
from a3d.synth.agreement import (
    amodal_contains_visible,
    exact_depth_in_boxes,
    floor_height_spread,
    sensed_inside_shares,
)
from a3d.synth.cli import frame_seed
from a3d.synth.sensor import SENSORS


def check(seed: int, config: SceneConfig) -> tuple[list[tuple[str, float, float]], bool, bool, float]:
    cv2.setNumThreads(1)
    f = generate_frame(seed, config)
    shares = sensed_inside_shares(f)
    return shares, exact_depth_in_boxes(f), amodal_contains_visible(f), floor_height_spread(f)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--sensor", choices=tuple(SENSORS), default="a3d")
    args = parser.parse_args()
    config = replace(SceneConfig(), depth_sensor=SENSORS[args.sensor])
    seeds = [frame_seed(args.seed, i) for i in range(args.frames)]
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        results = list(tqdm(pool.imap(partial(check, config=config), seeds), total=len(seeds), unit="frame"))
    rows = [r for shares, *_ in results for r in shares]
    depth = np.array([z for _, z, _ in rows])
    share = np.array([s for _, _, s in rows])
    print(f"sensor {args.sensor}, {args.frames} frames (seed {args.seed}): {len(rows)} annotated objects")
    print("depth band    objects  < 95 % in box+5cm  worst share")
    for lo in np.arange(0.0, 8.0, 1.0):
        m = (depth >= lo) & (depth < lo + 1)
        if m.any():
            below = int((share[m] < 0.95).sum())
            print(f"{lo:3.0f}-{lo + 1:.0f} m   {m.sum():9d}  {below:17d}  {share[m].min():11.4f}")
    worst = int(np.argmin(share))
    failing = int((share < 0.95).sum())
    where = f"({rows[worst][0]} at {depth[worst]:.2f} m)"
    print(f"all           {len(rows):7d}  {failing:17d}  {share[worst]:11.4f} {where}")
    exact_bad = sum(not ok for _, ok, _, _ in results)
    amodal_bad = sum(not ok for _, _, ok, _ in results)
    spreads = np.array([s for *_, s in results])
    spread = float(np.nanmax(spreads))
    print(f"frames with exact depth outside a box (1 mm): {exact_bad}")
    print(f"frames with an amodal 2D box not containing its visible box: {amodal_bad}")
    floors = int(np.isfinite(spreads).sum())
    print(f"largest noise-free floor height spread in the tilt frame: {spread * 100:.2f} cm (bar < 2 cm)")
    print(f"  over the {floors} frames with floor in view")
    return int(failing > 0 or exact_bad > 0 or amodal_bad > 0 or spread >= 0.02)


if __name__ == "__main__":
    sys.exit(main())
