"""Registration end to end: detections on registered depth vs on depth the colour camera saw.

For each of ``--frames`` a3d-synth frames (noise-free, the NYUv2 crop size) the depth is rendered
twice: in the colour camera itself, and by an offset depth camera (5 cm beside it, turned 2
degrees, 1.5 times the resolution, as ``tests/test_registration.py``'s) whose depth
``a3d.runtime.frontend.registration`` then registers to colour. It reports the share of pixels
both have where the two depths agree to 1 mm, and mAP@0.25 (over the classes present) of the
model on both versions of the frames, gravity estimated from the depth in both.

    .venv/bin/python bench/registration.py --frames 8 --seed 0 --model samples/model.onnx
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import cv2
import numpy as np
from tqdm import tqdm

from a3d.runtime import Detector
from a3d.runtime.evaluation.metric import EvalConfig, FrameTruth, evaluate
from a3d.runtime.frontend.registration import register_depth
from a3d.synth.cli import frame_seed
from a3d.synth.depth_camera import offset_depth_camera, render_depth_from
from a3d.synth.scene import SceneConfig, generate_frame

IOU = 0.25


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", default="samples/model.onnx")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    cv2.setNumThreads(args.threads)
    detector = Detector.load(args.model, threads=args.threads)
    config = replace(SceneConfig(), noise=False)
    calibration, depth_size = offset_depth_camera(config.image_size)
    truth, own, registered = {}, {}, {}
    within = both = 0
    for i in tqdm(range(args.frames), desc="frames", file=sys.stderr):
        seed = frame_seed(args.seed, i)
        frame = generate_frame(seed, config)
        name = f"synth_{i:06d}"
        truth[name] = FrameTruth(frame.gt.class_ids, frame.gt.boxes3d, frame.R_tilt)
        seen = render_depth_from(seed, config, calibration, depth_size)
        depth = register_depth(seen, calibration, config.intrinsics, config.image_size)
        have = (depth > 0) & (frame.depth_exact > 0)
        within += int(np.count_nonzero(np.abs(depth - frame.depth_exact)[have] <= 0.001))
        both += int(np.count_nonzero(have))
        rgb = np.ascontiguousarray(frame.color[..., ::-1])
        own[name] = detector.detect(rgb, frame.depth_exact, config.intrinsics, name=name)
        registered[name] = detector.detect(rgb, depth, config.intrinsics, name=name)
    scores = {
        label: evaluate(truth, detections, EvalConfig(iou_thresholds=(IOU,))).map_present(IOU)
        for label, detections in (("colour camera's depth", own), ("registered depth", registered))
    }
    print(f"frames: {args.frames} (seed {args.seed}), {config.image_size[0]}x{config.image_size[1]}")
    print(f"depth within 1 mm of the colour camera's: {100 * within / both:.2f} % of {both} pixels both have")
    for label, value in scores.items():
        print(f"mAP@{IOU} (classes present), {label}: {100 * value:.2f}")
    difference = 100 * (scores["registered depth"] - scores["colour camera's depth"])
    print(f"difference: {difference:+.2f} points")
    return 0


if __name__ == "__main__":
    sys.exit(main())
