"""Accuracy and speed of the runtime front end on frames with ground truth (e.g. a3d-synth's test split).

Per frame: hole filling, surface normals, gravity (R_tilt) estimation, and lifting of the
ground-truth instance masks to initial 3D boxes (SPEC.md "Proposals and 3D box initialisation"),
plus the lifting of the frame's real proposals (a3d.runtime.proposals, 2000 at most) for timing.

Reports: gravity angle error vs the frame's R_tilt (median, 95th percentile; targets <= 1.5 and
<= 5 degrees); initial-centre distance to the true amodal centre for the (nearly) fully visible
objects (visible 2D box covering >= 90% of the amodal 2D box; target median <= 15 cm) and for
all objects, and the 3D IoU of the initial boxes built with the class mean sizes (over the
folder's objects); per-stage times (median and max, ms).

    .venv/bin/python bench/gravity_lifting.py /tmp/synth_small/test [--limit 50] [--no-proposals]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from pathlib import Path

import numpy as np
from a3d.runtime.classes import NUM_CLASSES
from a3d.runtime.depth import fill_depth
from a3d.runtime.frames import (
    list_frames,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
)
from a3d.runtime.geometry import iou_2d, iou_3d
from a3d.runtime.gravity import estimate_gravity
from a3d.runtime.lifting import initial_boxes, lift
from a3d.runtime.normals import surface_normals


def _ms(times: list[float]) -> str:
    return f"median {1e3 * np.median(times):6.1f} ms, max {1e3 * np.max(times):6.1f} ms (n={len(times)})"


def _timed(times: dict[str, list[float]], stage: str, fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    times.setdefault(stage, []).append(time.perf_counter() - t0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="frame folder with NAME.meta.json R_tilt, gt and instances")
    parser.add_argument("--limit", type=int, default=0, help="use at most this many frames (0 = all)")
    parser.add_argument("--no-proposals", action="store_true", help="skip the real-proposal lifting timing")
    args = parser.parse_args()

    refs = list_frames(args.folder)
    if args.limit:
        refs = refs[: args.limit]
    folder_k = read_folder_intrinsics(args.folder)
    propose = None
    if not args.no_proposals:
        from a3d.runtime.proposals import propose

    times: dict[str, list[float]] = {}
    grav_err: list[float] = []
    statuses: Counter[str] = Counter()
    rows = []  # (class id, visible fraction, distance, initial centre, gt box, R_tilt) per object
    for ref in refs:
        frame = read_frame(ref, folder_k)
        K = frame.intrinsics
        filled = _timed(times, "fill_depth", fill_depth, frame.depth)
        _timed(times, "surface_normals", surface_normals, frame.depth, K)
        est = _timed(times, "gravity", estimate_gravity, frame.depth, K)
        statuses[est.status] += 1
        if frame.R_tilt is not None:
            cos = float(np.clip(est.gravity @ frame.R_tilt[1], -1.0, 1.0))  # row 1 of R_tilt = gravity
            grav_err.append(np.degrees(np.arccos(cos)))
        gt, inst = read_ground_truth(ref), read_instances(ref)
        if gt is not None and inst is not None and len(gt):
            masks = inst[None] == gt.instance_ids[:, None, None].astype(inst.dtype)
            present = masks.any(axis=(1, 2))
            lifted = _timed(times, "lift_gt_masks", lift, masks[present], frame.depth, filled, K)
            boxes = gt.boxes3d[present]
            vis = gt.boxes2d_visible[present]
            amodal = gt.boxes2d_amodal[present]
            frac = np.diag(iou_2d(vis, amodal))  # the visible box lies inside the amodal one
            dist = np.linalg.norm(lifted.centers - boxes[:, :3], axis=1)
            for i in np.flatnonzero(lifted.valid):
                rows.append(
                    (gt.class_ids[present][i], frac[i], dist[i], lifted.centers[i], boxes[i], frame.R_tilt)
                )
        if propose is not None:
            props = _timed(times, "propose", propose, frame.color, filled, K)
            _timed(times, "lift_proposals", lift, props, frame.depth, filled, K)
            times.setdefault("n_proposals", []).append(len(props) / 1e3)

    print(f"{len(refs)} frames from {args.folder}")
    if grav_err:
        e = np.asarray(grav_err)
        print(
            f"gravity: angle error median {np.median(e):.2f} deg, p95 {np.percentile(e, 95):.2f} deg, "
            f"max {e.max():.2f} deg (targets <= 1.5, <= 5); status {dict(statuses)}"
        )
    if rows:
        cls = np.array([r[0] for r in rows])
        frac = np.array([r[1] for r in rows])
        dist = np.array([r[2] for r in rows])
        mean_sizes = np.zeros((NUM_CLASSES, 3))
        for c in np.unique(cls):
            mean_sizes[c] = np.mean([r[4][3:6] for r in rows if r[0] == c], axis=0)
        ious = np.array(
            [
                iou_3d(initial_boxes(r[3][None], mean_sizes)[0, r[0]][None], r[4][None], r[5])[0, 0]
                for r in rows
            ]
        )
        full = frac >= 0.9
        for name, sel in (("fully visible", full), ("all objects", np.ones_like(full))):
            if sel.any():
                print(
                    f"lifting, {name} ({int(sel.sum())}): centre distance median "
                    f"{100 * np.median(dist[sel]):.1f} cm, p90 {100 * np.percentile(dist[sel], 90):.1f} cm "
                    f"(target median <= 15 cm); initial-box 3D IoU median {np.median(ious[sel]):.3f}, "
                    f">= 0.25: {np.mean(ious[sel] >= 0.25):.0%}"
                )
    for stage, t in times.items():
        if stage == "n_proposals":
            print(f"proposals per frame: median {1e3 * np.median(t):.0f}, max {1e3 * np.max(t):.0f}")
        else:
            print(f"time {stage:16s} {_ms(t)}")


if __name__ == "__main__":
    main()
