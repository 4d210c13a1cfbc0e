"""Write a small .rrd through a3d's own viewer module, for the browser check without a model.

A synthetic frame (a3d.synth) is logged as if it had been detected: its ground-truth boxes become
the detections (class ids, score 1.0, amodal 2D boxes), so the recording has exactly the entity
tree and default blueprint that ``a3d-run --save`` writes.

    .venv/bin/python -m bench.make_demo_recording /tmp/a3d_demo.rrd [--seed 1] [--frames 1]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import rerun as rr

from a3d.runtime.viewer import view as viewer
from a3d.synth import SceneConfig, generate_frame


def write_demo_recording(path: Path, seed: int = 1, frames: int = 1) -> list[str]:
    """Log ``frames`` synthetic frames (seeds seed, seed+1, ...) to ``path``; return frame 0's class names."""
    args = argparse.Namespace(
        headless=True, connect=False, serve=False, url=None, save=str(path), stdout=False
    )
    rec = viewer.open_recording(args)
    viewer.log_static(rec)
    first: list[str] = []
    for i in range(frames):
        frame = generate_frame(seed + i, SceneConfig())
        gt = frame.gt
        first = first or list(gt.classes)
        viewer.log_frame(
            rec,
            i,
            color=frame.color,
            depth_m=frame.depth,
            K=frame.intrinsics,
            R_tilt=frame.R_tilt,
            class_ids=gt.class_ids,
            scores=np.ones(len(gt), dtype=np.float64),
            boxes2d=gt.boxes2d_amodal,
            boxes3d=gt.boxes3d,
        )
    rec.flush()
    rr.disconnect(rec)
    return first


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the .rrd to write")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--frames", type=int, default=1)
    args = parser.parse_args()
    classes = write_demo_recording(args.out, args.seed, args.frames)
    print(f"{args.out}: {args.frames} frame(s); frame 0 boxes: {', '.join(classes) or 'none'}")


if __name__ == "__main__":
    main()
