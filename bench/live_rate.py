"""The live loop's rate: the bundled model at 480 x 640, per-stage times, proposal recall and mAP.

a3d-synth frames of held-out seeds are rendered in memory at 480 x 640 (a Kinect-like camera,
fx = fy = 525) and run through a3d.runtime.pipeline (prepare / infer / finish) with the bundled
model (the bundled live model, 2 threads) and at most 500 proposals, for each proposal setting in
VARIANTS: the model's own, a3d-run's live front end, and others spelled out (coarser working
resolution, fewer superpixels, fewer grouping strategies, fewer pair candidates). Per variant it
prints the median time of every stage (wall, ms), the front end (depth fill + gravity +
proposals + lifting; target <= 40 ms), the end-to-end frames/s (1 / median frame time), proposal
recall@0.5 (share of ground-truth visible 2D boxes matched by a proposal at IoU >= 0.5) and
mAP@0.25 over the 19 classes (a3d.runtime.evaluation.metric), so a speed-up's cost in accuracy
is seen beside it. The front end's process CPU time (the prepare stage) is printed beside its
wall time: on a loaded machine it is the steadier measure of the work itself.

    .venv/bin/python -m bench.live_rate [--first 910000] [--count 12] [--variants model live s4n300k6p150]
        [--detector yolox-nano]

``--detector`` adds a 2D detector's boxes to the RoIs (a3d.runtime.detector2d, the ``real``
pipeline's): its time is the stage ``detector2d``, counted in the front end.
"""

from __future__ import annotations

import argparse
import os
import re
import time
from dataclasses import replace

import numpy as np

from a3d.runtime.detector2d import Detector2D
from a3d.runtime.evaluation.metric import FrameTruth, evaluate
from a3d.runtime.frontend.proposals import live_proposals
from a3d.runtime.models import model_path
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import STAGES, PipelineConfig, finish, infer, prepare
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics, iou_2d
from bench.edge_report import cpu_description

SIZE = (480, 640)
CAMERA = Intrinsics(525.0, 525.0, 319.5, 239.5)
FRONT_END = ("depth_fill", "gravity", "proposals", "lifting")
MAX_PROPOSALS = 500


def _variant(config: PipelineConfig, name: str) -> PipelineConfig:
    """The proposal setting ``name`` on top of the model's: ``model``, ``live`` (a3d-run's live front end,
    a3d.runtime.frontend.proposals.live_proposals), or ``sS[nN][kK][pP]`` for working
    resolution 1/S, about N superpixels, the first K grouping strategies and pairs among the best P regions
    (e.g. ``s4n300k6p150``)."""
    p = config.proposals
    if name == "model":
        return config
    if name == "live":
        return replace(config, proposals=live_proposals(p))
    match = re.fullmatch(r"s(\d+)(?:n(\d+))?(?:k(\d+))?(?:p(\d+))?", name)
    if match is None:
        raise SystemExit(f"--variants: {name!r} is neither 'model' nor sS[nN][kK][pP]")
    scale, n, k, parts = match.groups()
    superpixels = replace(p.superpixels, n_segments=int(n)) if n else p.superpixels
    strategies = p.strategies[: int(k)] if k else p.strategies
    pairs = replace(p.pairs, parts=int(parts)) if parts else p.pairs
    proposals = replace(p, scale=int(scale), superpixels=superpixels, strategies=strategies, pairs=pairs)
    return replace(config, proposals=proposals)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, default=910_000, help="first seed (held out of training)")
    parser.add_argument("--count", type=int, default=12)
    parser.add_argument("--model", default=str(model_path("live")))
    parser.add_argument("--variants", nargs="+", default=["model", "live"])
    parser.add_argument("--detector", help="a 2D detector whose boxes join the RoIs (e.g. yolox-nano)")
    args = parser.parse_args()
    from a3d.synth.scene import SceneConfig, generate_frame

    scene = SceneConfig(image_size=SIZE, intrinsics=CAMERA)
    frames = []
    for seed in range(args.first, args.first + args.count):
        f = generate_frame(seed, scene)
        frames.append((Frame(f"s{seed}", f.color[..., ::-1].copy(), f.depth, f.intrinsics), f.gt, f.R_tilt))
    model = DetectorModel.load(args.model, threads=2)
    base = PipelineConfig.from_metadata(
        model.metadata, proposal_source="compute", max_proposals=MAX_PROPOSALS
    )
    front_end = FRONT_END
    if args.detector:
        base = replace(base, detector=Detector2D.load(args.detector))
        front_end = (*FRONT_END, "detector2d")
    print(
        f"{args.count} a3d-synth frames at {SIZE[0]} x {SIZE[1]}, seeds {args.first}+, model {args.model}, "
        f"2D detector {args.detector or 'none'}, "
    )
    print(f"at most {MAX_PROPOSALS} proposals, 2 threads; {cpu_description()}")
    print(f"load average {os.getloadavg()[0]:.1f}")
    for name in args.variants:
        config = _variant(base, name)
        times: dict[str, list[float]] = {}
        cpu: list[float] = []
        matched = total = 0
        truths, detections = {}, {}
        for i, (frame, gt, R_tilt) in enumerate(frames):
            start = time.process_time()
            prepared = prepare(frame, config)
            if i:
                cpu.append(1e3 * (time.process_time() - start))
            det = finish(prepared, infer(model, prepared), config)
            if i:  # the first frame warms the caches up
                for stage, seconds in det.timing.items():
                    times.setdefault(stage, []).append(1e3 * seconds)
            if len(gt):
                boxes = prepared.native_boxes.reshape(-1, 4)
                best = iou_2d(gt.boxes2d_visible, boxes).max(axis=1) if len(boxes) else np.zeros(len(gt))
                matched += int((best >= 0.5).sum())
                total += len(gt)
            truths[frame.name] = FrameTruth(gt.class_ids, gt.boxes3d, R_tilt)
            detections[frame.name] = det
        result = evaluate(truths, detections)
        med = {stage: float(np.median(t)) for stage, t in times.items()}
        front = float(np.median(np.sum([times[s] for s in front_end], axis=0)))
        stages = ", ".join(f"{s} {med[s]:.0f}" for s in STAGES if s in med)
        print(
            f"{name:7s} front end {front:5.0f} ms (target <= 40; CPU {np.median(cpu):4.0f} ms), "
            f"frame {med['total']:5.0f} ms = "
            f"{1e3 / med['total']:4.1f} frames/s; recall@0.5 {matched / max(total, 1):.3f}, "
            f"mAP@0.25 {100 * result.map_all(0.25):.1f}\n        stages (median ms): {stages}"
        )


if __name__ == "__main__":
    main()
