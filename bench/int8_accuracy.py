"""What int8 and SVD cost in accuracy: mAP@0.25 of compressed exports of a trained checkpoint.

Exports the checkpoint with a3d-export four ways (each verified on the first frames of the test
folder):

  fp32        the float32 graph (the reference)
  int8        --int8 (static QDQ, per-channel weights) calibrated on ``--calib`` frames
  svd         --svd RANK (fc6 and fc7 factorised), float32
  svd+int8    --svd RANK --int8, calibrated like int8

then runs each with a3d-run (``--headless``, the model's own settings) over the held-out frames
and scores them with a3d-eval (the paper's protocol, a3d.runtime.evaluation). Prints mAP@0.25
over the 19 classes (the paper's number) and over the classes present, and the difference to
fp32 in points. Target: svd+int8 costs <= 1.0 mAP point.

Calibrate on training frames, not on the held-out ones (the ranges would have seen the test set).

    .venv/bin/python bench/int8_accuracy.py RUN_DIR/checkpoint.pt TEST_FRAMES --calib TRAIN_FRAMES \\
        --work /tmp/a3d_int8 [--svd RANK] [--calib-frames 16] [--limit 0] [--threads 2]
e.g.
    .venv/bin/python bench/int8_accuracy.py /tmp/a3d_dev/runs/A/checkpoint.pt \\
        /tmp/a3d_dev/synth/s300/test --calib /tmp/a3d_dev/synth/s300/train --work /tmp/a3d_int8

Writes WORK/VARIANT.onnx (the SVD ones named with their rank, e.g. svd128+int8.onnx),
WORK/VARIANT.jsonl, WORK/eval_VARIANT/eval.json and WORK/summary.json; ``--reuse`` keeps the
exports already in WORK (e.g. to try another rank; they must come from the same checkpoint).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from edge_speed import BIN, export_model, frame_subset  # bench/ is the script's folder, first on sys.path

TARGET_POINTS = 1.0
PRIMARY_IOU = "0.25"


def variants(svd: int) -> dict[str, dict]:
    """a3d-export options per variant (export_model's keywords)."""
    return {"fp32": {}, "int8": {"int8": True}, "svd": {"svd": svd}, "svd+int8": {"svd": svd, "int8": True}}


def default_rank(checkpoint: Path) -> int:
    """A quarter of the checkpoint network's fc6 width."""
    from a3d.train.checkpoint import load_checkpoint
    from a3d.train.config import TrainConfig

    config = TrainConfig.from_json(load_checkpoint(checkpoint)["config"], str(checkpoint))
    return max(1, config.net.fc6 // 4)


def detect_and_score(model: Path, frames: Path, work: Path, name: str, threads: int) -> dict:
    """a3d-run then a3d-eval on ``frames``; the eval.json "map" entry and the run's seconds."""
    detections = work / f"{name}.jsonl"
    start = time.perf_counter()
    subprocess.run([str(BIN / "a3d-run"), str(frames), "--model", str(model), "--output", str(detections),
                    "--threads", str(threads), "--headless"], check=True)  # fmt: skip
    seconds = time.perf_counter() - start
    out = work / f"eval_{name}"
    subprocess.run([str(BIN / "a3d-eval"), str(frames), "--detections", str(detections), "--out", str(out)],
                   check=True, stdout=subprocess.DEVNULL)  # fmt: skip
    return {"map": json.loads((out / "eval.json").read_text())["map"], "run_seconds": seconds}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a3d-train checkpoint (RUN_DIR/checkpoint.pt)")
    parser.add_argument("frames", type=Path, help="held-out frames with ground truth")
    parser.add_argument("--calib", type=Path, required=True, help="calibration frames (training split)")
    parser.add_argument("--calib-frames", type=int, default=16)
    parser.add_argument(
        "--svd",
        type=int,
        help="fc6/fc7 SVD rank (default: a quarter of fc6's width, "
        "as 1024 of 4096 for the paper's network in bench/edge_speed.py)",
    )
    parser.add_argument("--work", type=Path, default=Path("/tmp/a3d_int8_accuracy"))
    parser.add_argument("--limit", type=int, default=0, help="first N held-out frames (0: all)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--reuse", action="store_true", help="keep exports already in WORK (same checkpoint!)"
    )
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    frames = frame_subset(args.frames, args.work / "frames", args.limit) if args.limit else args.frames
    args.svd = args.svd or default_rank(args.checkpoint)
    results = {}
    for name, options in variants(args.svd).items():
        stem = name.replace("svd", f"svd{args.svd}")
        model = args.work / f"{stem}.onnx"
        if not (args.reuse and model.is_file()):
            export_model(args.checkpoint, model, frames, calib=args.calib, calib_frames=args.calib_frames,
                         threads=args.threads, **options)  # fmt: skip
        results[name] = detect_and_score(model, frames, args.work, stem, args.threads)

    base = results["fp32"]["map"][PRIMARY_IOU]
    print(f"\nmAP@{PRIMARY_IOU} of {args.checkpoint} on {frames} (percent; delta vs fp32 in points)")
    print(f"  {'variant':10s}{'19 classes':>12s}{'delta':>8s}{'present':>10s}{'delta':>8s}{'a3d-run s':>11s}")
    for name, result in results.items():
        m = result["map"][PRIMARY_IOU]
        deltas = [100 * (m[k] - base[k]) for k in ("all_classes", "present_classes")]
        seconds = result["run_seconds"]
        print(f"  {name:10s}{100 * m['all_classes']:12.2f}{deltas[0]:+8.2f}"
              f"{100 * m['present_classes']:10.2f}{deltas[1]:+8.2f}{seconds:11.1f}")  # fmt: skip
    cost = 100 * (base["all_classes"] - results["svd+int8"]["map"][PRIMARY_IOU]["all_classes"])
    ok = cost <= TARGET_POINTS
    verdict = "PASS" if ok else "FAIL"
    print(f"  [{verdict}] svd {args.svd} + int8 costs <= {TARGET_POINTS} mAP point: {cost:+.2f}")
    summary = {"checkpoint": str(args.checkpoint), "frames": str(frames), "svd": args.svd,
               "calib": str(args.calib), "results": results, "cost_points": cost, "pass": ok}  # fmt: skip
    (args.work / "summary.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
