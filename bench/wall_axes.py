"""How far from a wall direction a box's yaw is turned onto it (a3d.runtime.postprocess.wall_axes).

    .venv/bin/python -m bench.wall_axes --synthetic /tmp/v350/test --real REAL_FRAMES --angles 0,10,20,30,45

For each ``SNAP_DEG`` (0: no box turned; 45: every box squared to the walls) the bundled pipeline
``real``: on ``--synthetic`` a3d-synth frames with ground truth (the angle was chosen on 350
frames of seed 2031, which no other benchmark uses: bench.depth_support's command makes them),
mAP@0.25 over their classes and the doors' AP (thin boxes, which a wrong yaw loses whole); on
``--real`` the real frames of bench.real_frames, its 2D counts at 0.5 and its 3D mAP@0.25 and
median 3D IoU (its files under OUT/ANGLE).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from a3d.runtime.postprocess import wall_axes
from bench.depth_support import floats, real_frames_result, real_result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--synthetic", type=Path, help="a3d-synth frames with ground truth")
    p.add_argument("--real", type=Path, help="the real frames of bench.real_frames")
    p.add_argument("--angles", type=floats, default=[0.0, 10.0, 20.0, 30.0, 45.0])
    p.add_argument("--out", type=Path, default=Path("/tmp/bench_wall_axes"))
    args = p.parse_args(argv)
    if args.synthetic is None and args.real is None:
        p.error("give --synthetic FOLDER, --real FOLDER or both")
    shipped = wall_axes.SNAP_DEG
    print("| SNAP_DEG | synthetic mAP@0.25 | doors AP@0.25 | real: found at >= 0.5 | right / detections "
          "| real 3D mAP@0.25 | median 3D IoU |")  # fmt: skip
    print("| ---: " * 7 + "|")
    for angle in args.angles:
        wall_axes.SNAP_DEG = angle
        row = [f"{angle:g}"]
        if args.synthetic is not None:
            result = real_result(args.synthetic)
            doors = next((c for c in result.classes if c.name == "door" and c.num_gt), None)
            row += [f"{100 * result.map_present(0.25):.2f}", f"{100 * doors.ap[0.25]:.1f}" if doors else "-"]
        else:
            row += ["-", "-"]
        if args.real is not None:
            found = real_frames_result(args.real, args.out / f"{angle:g}")
            total, three = found["total"], found["3d"]
            right = f"{total['right']} / {total['detections']} ({100 * total['precision']:.0f} %)"
            row += [f"{total['found']} of {total['objects']}", right, f"{100 * three['map']:.1f}"]
            row.append(f"{three['median_iou']:.2f}")
        else:
            row += ["-"] * 4
        print("| " + " | ".join(row) + " |", flush=True)
    wall_axes.SNAP_DEG = shipped
    return 0


if __name__ == "__main__":
    sys.exit(main())
