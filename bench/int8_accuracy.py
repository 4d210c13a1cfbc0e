"""What int8 and SVD cost in accuracy: mAP@0.25 of compressed exports of a trained checkpoint.

Exports the checkpoint with a3d-export four ways (each verified on the first frames of the test
folder):

  fp32        the float32 graph (the reference)
  int8        --int8 (static QDQ, per-channel weights) calibrated on ``--calib`` frames
  svd         --svd RANK (fc6 and fc7 factorised), float32
  svd+int8    --svd RANK --int8, calibrated like int8

then runs each with a3d-run (``--headless``, the model's own settings) over the held-out frames
and scores them with a3d-eval (the paper's protocol, a3d.runtime.evaluation.metric). Prints mAP@0.25
over the 19 classes (the paper's number) and over the classes present, the difference to fp32 in
points and, because a one-point difference is near the noise of a few hundred frames, a 90 %
paired bootstrap interval of each variant's cost (``--bootstrap`` resamples of the frames, the
same resample for fp32 and the variant). Target: svd+int8 costs <= 1.0 mAP point.

Calibrate on training frames, not on the held-out ones (the ranges would have seen the test set).

    .venv/bin/python -m bench.int8_accuracy RUN_DIR/checkpoint.pt TEST_FRAMES --calib TRAIN_FRAMES \\
        --work /tmp/a3d_int8 [--svd RANK] [--calib-frames 16] [--limit 0] [--bootstrap 100] [--reuse]
e.g., held-out frames from another generator seed than the training set's:
    .venv/bin/a3d-synth /tmp/a3d_heldout --frames 200 --seed 777 --split test=1.0
    .venv/bin/python -m bench.int8_accuracy RUN_DIR/checkpoint.pt /tmp/a3d_heldout/test \\
        --calib SYNTH/train --work /tmp/a3d_int8

Time: each export and a3d-run takes a minute or two for a CPU preset on 200 frames; the
bootstrap about 4 s per resample there (4 evaluations).

Writes WORK/VARIANT.onnx (the SVD ones named with their rank, e.g. svd128+int8.onnx),
WORK/VARIANT/detections.jsonl, WORK/VARIANT/eval/eval.json (bench.train_synth.run_and_score, with
the a3d-run and a3d-eval logs beside them) and WORK/summary.json; ``--reuse`` keeps the
exports and detections already in WORK (e.g. to try another rank; they must come from the same
checkpoint and frames).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bench.edge_speed import export_model, frame_subset
from bench.train_synth import run_and_score

TARGET_POINTS = 1.0
PRIMARY_IOU = 0.25


def variants(svd: int) -> dict[str, dict]:
    """a3d-export options per variant (export_model's keywords)."""
    return {"fp32": {}, "int8": {"int8": True}, "svd": {"svd": svd}, "svd+int8": {"svd": svd, "int8": True}}


def default_rank(checkpoint: Path) -> int:
    """A quarter of the checkpoint network's fc6 width."""
    from a3d.train.checkpoint import checkpoint_config

    return max(1, checkpoint_config(checkpoint).net.fc6 // 4)


def bootstrap_maps(
    frames: Path, detections: dict[str, Path], resamples: int, seed: int = 0
) -> dict[str, np.ndarray]:
    """mAP@0.25 (points) of every variant on each of ``resamples`` paired resamples of the annotated
    frames (drawn with replacement; all variants scored on the same draw with
    a3d.runtime.evaluation.metric, as a3d-eval scores): any difference of two variants is paired."""
    from a3d.runtime.evaluation.metric import EvalConfig, evaluate
    from a3d.runtime.evaluation.truth import load_truth
    from a3d.runtime.io.detections_io import read_detections

    truth, _ = load_truth(frames)
    names = sorted(truth)
    lines = {v: {d.frame: d for d in read_detections(path)} for v, path in detections.items()}
    rng = np.random.default_rng(seed)
    maps: dict[str, list[float]] = {v: [] for v in lines}
    for _ in range(resamples):
        draw = {f"{i}:{n}": n for i, n in enumerate(rng.choice(names, len(names)))}  # unique keys
        sample = {key: truth[name] for key, name in draw.items()}
        for v, det in lines.items():
            picked = {k: det[n] for k, n in draw.items() if n in det}
            maps[v].append(100 * evaluate(sample, picked, EvalConfig()).map_all(PRIMARY_IOU))
    return {v: np.asarray(m) for v, m in maps.items()}


def interval_90(differences: np.ndarray) -> list[float]:
    """The 5th and 95th percentiles of paired bootstrap differences."""
    return np.percentile(differences, [5, 95]).tolist()


def bootstrap_costs(
    frames: Path, detections: dict[str, Path], resamples: int, seed: int = 0, reference: str = "fp32"
) -> dict[str, list]:
    """90 % interval (points) of the ``reference`` variant's mAP minus each other variant's over
    ``resamples`` paired resamples of the annotated frames (bootstrap_maps)."""
    maps = bootstrap_maps(frames, detections, resamples, seed)
    return {v: interval_90(maps[reference] - m) for v, m in maps.items() if v != reference}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a3d-train checkpoint (RUN_DIR/checkpoint.pt)")
    parser.add_argument("frames", type=Path, help="held-out frames with ground truth")
    parser.add_argument("--calib", type=Path, required=True, help="calibration frames (training split)")
    parser.add_argument("--calib-frames", type=int, default=16)
    parser.add_argument("--svd", type=int, help="fc6/fc7 SVD rank (default: a quarter of fc6's width, "
                        "as 1024 of 4096 for the paper's network in bench/edge_speed.py)")  # fmt: skip
    parser.add_argument("--work", type=Path, default=Path("/tmp/a3d_int8_accuracy"))
    parser.add_argument("--limit", type=int, default=0, help="first N held-out frames (0: all)")
    parser.add_argument("--bootstrap", type=int, default=100, help="paired resamples (0: none)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--reuse", action="store_true", help="keep exports and detections in WORK")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    frames = frame_subset(args.frames, args.work / "frames", args.limit) if args.limit else args.frames
    args.svd = args.svd or default_rank(args.checkpoint)
    results, detections = {}, {}
    for name, options in variants(args.svd).items():
        stem = name.replace("svd", f"svd{args.svd}")
        model = args.work / f"{stem}.onnx"
        if not (args.reuse and model.is_file()):
            export_model(args.checkpoint, model, frames, calib=args.calib, calib_frames=args.calib_frames,
                         threads=args.threads, **options)  # fmt: skip
        results[name] = run_and_score(model, frames, args.work / stem, args.threads, args.reuse)
        detections[name] = args.work / stem / "detections.jsonl"
    intervals = bootstrap_costs(frames, detections, args.bootstrap) if args.bootstrap else {}

    key = f"{PRIMARY_IOU:g}"
    base = results["fp32"]
    print(f"\nmAP@{key} of {args.checkpoint} on {frames}, SVD rank {args.svd} (percent; cost = fp32 minus "
          f"the variant, points; 90 % bootstrap interval over {args.bootstrap} resamples)")  # fmt: skip
    print(f"  {'variant':10s}{'19 classes':>11s}{'cost':>7s}{'interval':>16s}{'present':>9s}{'cost':>7s}"
          f"{'a3d-run s':>10s}")  # fmt: skip
    for name, result in results.items():
        costs = [100 * (base[k] - result[k]) for k in ("map25_all", "map25_present")]
        interval = "[{:+.2f}, {:+.2f}]".format(*intervals[name]) if name in intervals else ""
        seconds = result["detect_seconds"]
        print(f"  {name:10s}{100 * result['map25_all']:11.2f}{costs[0]:+7.2f}{interval:>16s}"
              f"{100 * result['map25_present']:9.2f}{costs[1]:+7.2f}{seconds:10.1f}")  # fmt: skip
    cost = 100 * (base["map25_all"] - results["svd+int8"]["map25_all"])
    ok = cost <= TARGET_POINTS
    verdict = "PASS" if ok else "FAIL"
    print(f"  [{verdict}] svd {args.svd} + int8 costs <= {TARGET_POINTS} mAP point: {cost:+.2f}")
    summary = {"checkpoint": str(args.checkpoint), "frames": str(frames), "svd": args.svd,
               "calib": str(args.calib), "results": results, "bootstrap_90": intervals,
               "cost_points": cost, "pass": ok}  # fmt: skip
    (args.work / "summary.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
