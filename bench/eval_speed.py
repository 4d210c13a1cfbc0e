"""Speed of the evaluator (a3d.runtime.evaluation.metric) at NYUv2 test-set scale, on one core.

Generates in memory 654 frames with a plausible ground truth (about 12 objects a frame, chairs
most common, class-typical sizes, random yaw and a small random gravity tilt) and, per frame,
100 detections for each of the 19 classes (1.24 M in all): noisy copies of the frame's objects
with higher scores, the rest scattered boxes; 2D boxes are the pinhole projections of the 3D
centres and sizes, so the 2D NMS has realistic overlaps. Then times ``evaluate`` with the
default 2D NMS (0.3) and without it. Target: < 30 s with NMS. Times are CPU seconds of this one
thread (``time.process_time``), robust to a busy machine; wall time is printed beside them.

    .venv/bin/python -m bench.eval_speed [--frames 654] [--per-class 100] [--seed 0] [--retilt] [--io]

``--retilt`` gives the detections a perturbed R_tilt (every frame takes the re-expression path);
``--io`` also times writing and reading the detections file (detections_io) in a temp folder.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core; must precede the numpy import

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from a3d.runtime.evaluation.metric import EvalConfig, FrameTruth, evaluate  # noqa: E402
from a3d.runtime.io.detections_io import FrameDetections, read_detections, write_detections  # noqa: E402
from a3d.runtime.structures.boxes import SIZE  # noqa: E402
from a3d.runtime.structures.classes import NUM_CLASSES, class_index  # noqa: E402
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS, NYU_CROP_SIZE, rtilt_from_pitch_roll  # noqa: E402

# Rough class sizes [l, w, h] in metres and relative frequencies of NYUv2-like scenes.
_SIZES = np.full((NUM_CLASSES, 3), 0.6)
_FREQ = np.ones(NUM_CLASSES)
for name, size, freq in (
    ("bed", (2.0, 1.6, 0.9), 2), ("chair", (0.6, 0.55, 0.9), 12), ("table", (1.2, 0.8, 0.75), 6),
    ("sofa", (1.9, 0.9, 0.85), 3), ("pillow", (0.5, 0.35, 0.2), 5), ("box", (0.4, 0.3, 0.3), 6),
    ("door", (0.9, 0.1, 2.0), 2), ("monitor", (0.5, 0.15, 0.4), 3), ("lamp", (0.35, 0.35, 0.6), 3),
):  # fmt: skip
    _SIZES[class_index(name)] = size
    _FREQ[class_index(name)] = freq
_FREQ /= _FREQ.sum()


def _boxes2d(boxes3d: np.ndarray) -> np.ndarray:
    """Pinhole box of each 3D box's centre and extent, clipped to the NYUv2 crop."""
    K = NYU_CROP_INTRINSICS
    H, W = NYU_CROP_SIZE
    x, y, z = boxes3d[:, 0], boxes3d[:, 1], np.maximum(boxes3d[:, 2], 0.5)
    half_u = K.fx * np.maximum(boxes3d[:, 3], boxes3d[:, 4]) / 2 / z
    half_v = K.fy * boxes3d[:, 5] / 2 / z
    u, v = K.cx + K.fx * x / z, K.cy + K.fy * y / z
    box = np.column_stack([u - half_u, v - half_v, u + half_u, v + half_v])
    return np.clip(box, -0.5, [W - 0.5, H - 0.5, W - 0.5, H - 0.5])


def _random_boxes(rng: np.random.Generator, class_ids: np.ndarray) -> np.ndarray:
    n = len(class_ids)
    centre = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-0.5, 1.0, n), rng.uniform(1.5, 6.0, n)])
    size = _SIZES[class_ids] * rng.uniform(0.8, 1.25, (n, 3))
    return np.column_stack([centre, size, rng.uniform(-np.pi / 2, np.pi / 2, n)])


def make_set(
    frames: int, per_class: int, seed: int, retilt: bool
) -> tuple[dict[str, FrameTruth], dict[str, FrameDetections]]:
    rng = np.random.default_rng(seed)
    truth, detections = {}, {}
    for f in range(frames):
        name = f"{f:04d}"
        R = rtilt_from_pitch_roll(rng.uniform(-0.15, 0.15), rng.uniform(-0.05, 0.05))
        gt_ids = rng.choice(NUM_CLASSES, size=int(np.clip(rng.poisson(12), 1, 40)), p=_FREQ)
        gt_boxes = _random_boxes(rng, gt_ids)
        truth[name] = FrameTruth(gt_ids, gt_boxes, R)
        det_ids = np.repeat(np.arange(NUM_CLASSES), per_class)
        det_boxes = _random_boxes(rng, det_ids)
        scores = rng.uniform(0.0, 0.6, len(det_ids))
        for c in np.unique(gt_ids):  # up to 3 noisy copies of each object, first rows of its class
            objects = gt_boxes[gt_ids == c]
            copies = np.repeat(objects, 3, axis=0)[:per_class]
            noise = rng.normal(0, 1, copies.shape) * [0.15, 0.05, 0.2, 0.1, 0.1, 0.05, 0.3]
            noisy = copies + noise
            noisy[:, SIZE] = np.maximum(noisy[:, SIZE], 0.05)
            rows = c * per_class + np.arange(len(copies))
            det_boxes[rows] = noisy
            scores[rows] = rng.uniform(0.3, 1.0, len(copies))
        R_det = rtilt_from_pitch_roll(rng.uniform(-0.15, 0.15), 0.0) if retilt else R
        detections[name] = FrameDetections(name, R_det, det_ids, scores, _boxes2d(det_boxes), det_boxes)
    return truth, detections


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=654)
    p.add_argument("--per-class", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--retilt", action="store_true", help="detections in a perturbed tilt frame")
    p.add_argument("--io", action="store_true", help="also time writing and reading the detections file")
    args = p.parse_args()
    cv2.setNumThreads(1)

    t0 = time.perf_counter()
    truth, detections = make_set(args.frames, args.per_class, args.seed, args.retilt)
    n_det = sum(len(d.scores) for d in detections.values())
    n_gt = sum(len(t.class_ids) for t in truth.values())
    elapsed = time.perf_counter() - t0
    print(f"generated {len(truth)} frames, {n_gt} objects, {n_det} detections in {elapsed:.1f} s")

    for label, config in (("2D NMS 0.3", EvalConfig()), ("no NMS", EvalConfig(nms_iou=None))):
        wall, cpu = time.perf_counter(), time.process_time()
        result = evaluate(truth, detections, config)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        kept = sum(c.num_det for c in result.classes)
        print(
            f"evaluate ({label}): {cpu:.2f} s CPU ({wall:.2f} s wall) for {kept} scored detections; "
            f"mAP@0.25 {100 * result.map_all(0.25):.1f}, mAP@0.5 {100 * result.map_all(0.5):.1f}; "
            f"{len(result.retilted_frames)} frames re-expressed"
        )
    if args.io:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "detections.jsonl"
            t0 = time.process_time()
            write_detections(path, detections.values())
            t1 = time.process_time()
            back = read_detections(path)
            t2 = time.process_time()
            size = path.stat().st_size / 1e6
        print(
            f"detections file: {size:.0f} MB, write {t1 - t0:.1f} s CPU, "
            f"read + validate {t2 - t1:.1f} s CPU ({len(back)} lines)"
        )


if __name__ == "__main__":
    main()
