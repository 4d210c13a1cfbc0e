"""Proposal recall and the time of the whole runtime front end, on frames with ground truth.

Per frame of a folder in the frame format (e.g. a3d-synth's test split): hole filling
(a3d.runtime.frontend.depth.fill_depth), gravity (a3d.runtime.frontend.gravity.estimate_rtilt),
segment proposals (a3d.runtime.frontend.proposals.propose) and lifting
(a3d.runtime.frontend.lifting.lift), each timed (wall clock,
the process's CPU time alongside; the machine's load average is printed because other work on
a 2-core machine inflates both). The proposals are broken down into their own stages
(PROPOSAL_STAGES: working images, superpixels, region graph, grouping, ranking, pairs, selection).
The proposal settings are a model's (`--model`, the bundled model by default), or a3d-run's live
front end of them (`--front-end live`); the first frame warms the caches up and is not timed.

Recall: the share of ground-truth `box2d_visible` boxes (the paper's gt2d_sel) matched by one of
the first N proposals at 2D IoU >= 0.5 and >= 0.7, for N in --counts. Objects whose visible
area (instance map) is below the proposals' `min_area` cannot be matched by a mask of at least
that area in general; recall without them is printed too.

Targets (issue): recall@0.5 >= 90 % with 1000 proposals and >= 95 % with 2000; fill + gravity +
proposals + lifting <= 0.25 s per 427 x 561 frame.

    .venv/bin/a3d-synth /tmp/synth_prop --frames 60 --seed 7
    .venv/bin/python -m bench.frontend /tmp/synth_prop/test [--limit 20] [--max-proposals 2000] \
        [--model samples/model.onnx] [--front-end live]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.gravity import estimate_rtilt
from a3d.runtime.frontend.lifting import lift
from a3d.runtime.frontend.proposals import PROPOSAL_STAGES, ProposalConfig, live_proposals, propose
from a3d.runtime.models import model_path
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.sources.folder import (
    list_frames,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
)
from a3d.runtime.structures.geometry import Intrinsics, iou_2d
from bench.edge_report import cpu_description

STAGES = ("fill_depth", "gravity", "proposals", "lifting")


def front_end(
    color: np.ndarray, depth: np.ndarray, K: Intrinsics, config: ProposalConfig
) -> tuple[dict[str, Any], dict[str, tuple[float, float]]]:
    """Run the four stages on one frame: their outputs and (wall, CPU) seconds, by stage name
    (the proposals' own stages too, wall only: CPU 0)."""
    outputs: dict[str, Any] = {}
    times: dict[str, tuple[float, float]] = {}
    proposal_stages: dict[str, float] = {}

    def timed(name: str, step: Callable[[], Any]) -> Any:
        w0, c0 = time.perf_counter(), time.process_time()
        outputs[name] = step()
        times[name] = (time.perf_counter() - w0, time.process_time() - c0)
        return outputs[name]

    filled = timed("fill_depth", partial(fill_depth, depth))
    timed("gravity", partial(estimate_rtilt, filled, K))
    props = timed("proposals", partial(propose, color, filled, K, config, proposal_stages))
    timed("lifting", partial(lift, props, depth, filled, K))
    times.update((name, (seconds, 0.0)) for name, seconds in proposal_stages.items())
    return outputs, times


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "folder", type=Path, help="frame folder with NAME.gt.json (e.g. OUT/test of a3d-synth)"
    )
    parser.add_argument("--limit", type=int, default=0, help="use the first N frames only (0 = all)")
    parser.add_argument("--max-proposals", type=int, default=2000)
    parser.add_argument("--model", default=str(model_path("live")), help="whose proposal settings run")
    parser.add_argument("--front-end", choices=("model", "live"), default="model")
    parser.add_argument("--counts", type=int, nargs="+", default=[10, 50, 100, 200, 500, 1000, 2000])
    args = parser.parse_args()

    model_config = DetectorModel.load(args.model, threads=1).metadata.proposals
    config = replace(model_config, max_proposals=args.max_proposals)
    if args.front_end == "live":
        config = replace(live_proposals(model_config), max_proposals=args.max_proposals)
    refs = [r for r in list_frames(args.folder) if r.gt_path is not None]
    if args.limit:
        refs = refs[: args.limit]
    if not refs:
        raise SystemExit(f"{args.folder}: no frames with ground truth")
    folder_k = read_folder_intrinsics(args.folder)

    wall = {s: [] for s in (*STAGES, *PROPOSAL_STAGES)}
    cpu = {s: [] for s in (*STAGES, *PROPOSAL_STAGES)}
    hits5, hits7, small, n_props = [], [], [], []
    for i, ref in enumerate(refs):
        frame = read_frame(ref, folder_k)
        gt = read_ground_truth(ref)
        outputs, times = front_end(frame.color, frame.depth, frame.intrinsics, config)
        for name, (w, c) in times.items():
            if i or len(refs) == 1:
                wall[name].append(w)
                cpu[name].append(c)
        props = outputs["proposals"]
        n_props.append(len(props))
        if gt is None or len(gt) == 0:
            continue
        iou = iou_2d(gt.boxes2d_visible, props.boxes) if len(props) else np.zeros((len(gt), 1))
        hits5.append(np.stack([iou[:, :n].max(axis=1, initial=0.0) >= 0.5 for n in args.counts], axis=1))
        hits7.append(np.stack([iou[:, :n].max(axis=1, initial=0.0) >= 0.7 for n in args.counts], axis=1))
        instances = read_instances(ref)
        if instances is None:
            small.append(np.zeros(len(gt), bool))
        else:
            area = np.bincount(instances.ravel(), minlength=int(gt.instance_ids.max()) + 1)
            small.append((gt.instance_ids > 0) & (area[gt.instance_ids] < config.min_area))

    h5, h7, tiny = np.concatenate(hits5), np.concatenate(hits7), np.concatenate(small)
    print(
        f"{len(refs)} frames, {h5.shape[0]} objects ({int(tiny.sum())} with < {config.min_area} visible px), "
        f"{np.mean(n_props):.0f} proposals per frame on average; load average {os.getloadavg()[0]:.1f}"
    )
    print(f"proposal settings: {args.front_end} front end of {args.model}; {cpu_description()}")
    print("proposals      " + " ".join(f"{n:>6d}" for n in args.counts))
    print("recall@0.5     " + " ".join(f"{x:6.3f}" for x in h5.mean(axis=0)))
    print("recall@0.7     " + " ".join(f"{x:6.3f}" for x in h7.mean(axis=0)))
    if tiny.any():
        print(f"@0.5 w/o <{config.min_area}px " + " ".join(f"{x:6.3f}" for x in h5[~tiny].mean(axis=0)))
        print(f"@0.7 w/o <{config.min_area}px " + " ".join(f"{x:6.3f}" for x in h7[~tiny].mean(axis=0)))
    print("stage (ms)       wall median   wall p90   cpu median")
    total_wall = np.sum([wall[s] for s in STAGES], axis=0)
    total_cpu = np.sum([cpu[s] for s in STAGES], axis=0)
    rows = [(s, wall[s], cpu[s]) for s in STAGES]
    at = STAGES.index("proposals") + 1
    rows[at:at] = [(f"  {s}", wall[s], None) for s in PROPOSAL_STAGES]
    for name, w, c in [*rows, ("total", total_wall, total_cpu)]:
        w_med, w_p90 = np.median(w) * 1e3, np.percentile(w, 90) * 1e3
        c_med = f"{np.median(c) * 1e3:12.1f}" if c is not None else ""
        print(f"{name:16s} {w_med:11.1f} {w_p90:10.1f} {c_med}")


if __name__ == "__main__":
    main()
