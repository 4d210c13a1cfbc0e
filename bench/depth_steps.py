"""How the constants of the pipeline's depth steps were chosen (docs/real-rooms.md, steps 6, 8, 9 and 10).

    .venv/bin/python -m bench.depth_steps walls --synthetic /tmp/v350/test --real REAL --values 0,10,20,30,45
    .venv/bin/python -m bench.depth_steps floor --synthetic /tmp/v350/test --real REAL --values 0,0.2,0.3,0.4
    .venv/bin/python -m bench.depth_steps hold --synthetic /tmp/v350/test --real REAL --values 0,0.05,0.1,0.15
    .venv/bin/python -m bench.depth_steps turn --synthetic /tmp/v350/test --real REAL --values inf,1.5,2,3

For each value of the step's constant, the bundled pipeline ``real``: on ``--synthetic`` a3d-synth
frames with ground truth (the constants were chosen on 350 frames of seed 2031, which no other
benchmark uses: bench.depth_support's command makes them), mAP@0.25 over their classes and what
the step is for: for ``walls`` (a3d.runtime.postprocess.wall_axes.SNAP_DEG, how far from a wall
direction a yaw is turned onto it; 0: none, 45: every box) the doors' AP@0.25 (thin boxes, which a
wrong yaw loses whole), for ``floor`` (a3d.runtime.postprocess.floor_contact.REACH_M, how far from
the floor a standing box's bottom is set onto it; 0: none), for ``hold``
(a3d.runtime.postprocess.hold_depth.MARGIN_M, how far from a box the depth is taken for its
object's and the box grown to hold it; 0: none), for ``turn``
(a3d.runtime.postprocess.long_axis.MIN_ELONGATION, how long the depth's footprint round a long
box must be for the box to be turned along it; inf: never) mAP@0.5 (where a few centimetres count); on
``--real`` the real frames of bench.real_frames (REAL), its 2D counts at 0.5 and its
3D mAP@0.25 and median 3D IoU (its files under OUT/VALUE).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from a3d.runtime.evaluation.metric import EvalResult
from a3d.runtime.postprocess import floor_contact, hold_depth, long_axis, wall_axes
from bench.depth_support import floats, real_frames_result, real_result


def doors_ap(result: EvalResult) -> str:
    doors = next((c for c in result.classes if c.name == "door" and c.num_gt), None)
    return f"{100 * doors.ap[0.25]:.1f}" if doors else "-"


def map_at_half(result: EvalResult) -> str:
    return f"{100 * result.map_present(0.5):.2f}"


@dataclass(frozen=True)
class Step:
    """A depth step's constant, and the synthetic column that shows what the step is for."""

    module: ModuleType
    constant: str
    column: str
    measure: Callable[[EvalResult], str]


STEPS = {
    "walls": Step(wall_axes, "SNAP_DEG", "doors AP@0.25", doors_ap),
    "floor": Step(floor_contact, "REACH_M", "mAP@0.5", map_at_half),
    "hold": Step(hold_depth, "MARGIN_M", "mAP@0.5", map_at_half),
    "turn": Step(long_axis, "MIN_ELONGATION", "mAP@0.5", map_at_half),
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("step", choices=sorted(STEPS))
    p.add_argument("--synthetic", type=Path, help="a3d-synth frames with ground truth")
    p.add_argument("--real", type=Path, help="the real frames of bench.real_frames")
    p.add_argument("--values", type=floats, required=True, help="the constant's values, comma-separated")
    p.add_argument("--out", type=Path, default=Path("/tmp/bench_depth_steps"))
    args = p.parse_args(argv)
    if args.synthetic is None and args.real is None:
        p.error("give --synthetic FOLDER, --real FOLDER or both")
    step = STEPS[args.step]
    shipped = getattr(step.module, step.constant)
    print(f"| {step.constant} | synthetic mAP@0.25 | {step.column} | real: found at >= 0.5 "
          "| right / detections | real 3D mAP@0.25 | median 3D IoU |")  # fmt: skip
    print("| ---: " * 7 + "|")
    try:
        for value in args.values:
            setattr(step.module, step.constant, value)
            row = [f"{value:g}"]
            if args.synthetic is not None:
                result = real_result(args.synthetic)
                row += [f"{100 * result.map_present(0.25):.2f}", step.measure(result)]
            else:
                row += ["-", "-"]
            if args.real is not None:
                found = real_frames_result(args.real, args.out / args.step / f"{value:g}")
                total, three = found["total"], found["3d"]
                right = f"{total['right']} / {total['detections']} ({100 * total['precision']:.0f} %)"
                row += [f"{total['found']} of {total['objects']}", right, f"{100 * three['map']:.1f}"]
                row.append(f"{three['median_iou']:.2f}")
            else:
                row += ["-"] * 4
            print("| " + " | ".join(row) + " |", flush=True)
    finally:
        setattr(step.module, step.constant, shipped)
    return 0


if __name__ == "__main__":
    sys.exit(main())
