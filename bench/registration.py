"""Registration end to end: detections on registered depth vs on depth the colour camera saw.

For each of ``--frames`` a3d-synth frames (noise-free, the NYUv2 crop size) the depth is rendered
twice: in the colour camera itself, and by an offset depth camera
(``a3d.synth.depth_camera.offset_depth_camera``: 5 cm beside it, turned 2 degrees, 1.5 times the
resolution) whose depth, stored in millimetres as a sensor sends it, ``register_depth`` registers
to colour. It reports the share of pixels both have where the registered depth agrees with the
colour camera's to 1 mm, and mAP@0.25 (over the classes present) of the model on five versions
of the frames, gravity estimated from the depth in each: the colour camera's
exact depth and the registered depth; the noise floor, the exact depth plus uniform noise of at
most 1 mm (far below any sensor's: how far mAP moves for a change that carries no information);
and the pair as a sensor gives them, the a3d sensor's axial error (``a3d.synth.sensor.axial_noise``,
Gaussian and disparity steps, no holes) drawn in the colour camera, and drawn in the depth camera
before registration. Both differences, registered - colour camera, are judged against 1 point.
Proposals, the network's scores and the per-class AP of a few dozen objects react chaotically to
small depth changes, so the comparison needs hundreds of frames.

    .venv/bin/python -m bench.registration --frames 500 --seed 1 --model runtime/models/live.onnx
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
from a3d.runtime.models import model_path
from a3d.synth.cli import frame_seed
from a3d.synth.depth_camera import offset_depth_camera, render_depth_from
from a3d.synth.scene import SceneConfig, generate_frame
from a3d.synth.sensor import axial_noise

IOU = 0.25
EXACT, REGISTERED, FLOOR = "colour camera's depth", "registered depth", "colour camera's depth + 1 mm noise"
SENSED, SENSED_REGISTERED = "colour camera's sensed depth", "depth camera's sensed depth, registered"
LABELS = (EXACT, REGISTERED, FLOOR, SENSED, SENSED_REGISTERED)
NOISE_M = 0.001


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", default=str(model_path("live")))
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    cv2.setNumThreads(args.threads)
    detector = Detector.load(args.model, threads=args.threads)
    config = replace(SceneConfig(), noise=False)
    calibration, depth_size = offset_depth_camera(config.image_size)
    truth: dict[str, FrameTruth] = {}
    runs: dict[str, dict] = {label: {} for label in LABELS}
    within = both = 0
    for i in tqdm(range(args.frames), desc="frames", file=sys.stderr):
        seed = frame_seed(args.seed, i)
        frame = generate_frame(seed, config)
        name = f"synth_{i:06d}"
        truth[name] = FrameTruth(frame.gt.class_ids, frame.gt.boxes3d, frame.R_tilt)
        seen = np.round(render_depth_from(seed, config, calibration, depth_size) * 1000).astype(np.uint16)
        depth = register_depth(seen / 1000.0, calibration, config.intrinsics, config.image_size)
        have = (depth > 0) & (frame.depth_exact > 0)
        within += int(np.count_nonzero(np.abs(depth - frame.depth_exact)[have] <= 0.001))
        both += int(np.count_nonzero(have))
        rgb = np.ascontiguousarray(frame.color[..., ::-1])
        rng = np.random.default_rng(seed)
        noisy = np.where(
            frame.depth_exact > 0, frame.depth_exact + rng.uniform(-NOISE_M, NOISE_M, depth.shape), 0
        )
        # The a3d sensor's axial error in each camera (its own focal length), before registration.
        sensed = axial_noise(rng, frame.depth_exact, config.intrinsics.fx)
        sensed_seen = axial_noise(rng, seen / 1000.0, calibration.depth_intrinsics.fx)
        sensed_registered = register_depth(sensed_seen, calibration, config.intrinsics, config.image_size)
        versions = (frame.depth_exact, depth, noisy, sensed, sensed_registered)
        for label, metres in zip(LABELS, versions, strict=True):
            runs[label][name] = detector.detect(rgb, metres.astype(np.float32), config.intrinsics, name=name,
                                                score_threshold=0)  # all of them: the mAP's whole curve
    scores = {
        label: evaluate(truth, detections, EvalConfig(iou_thresholds=(IOU,))).map_present(IOU)
        for label, detections in runs.items()
    }
    print(f"frames: {args.frames} (seed {args.seed}), {config.image_size[0]}x{config.image_size[1]}")
    print(f"depth within 1 mm of the colour camera's: {100 * within / both:.2f} % of {both} pixels both have")
    for label, value in scores.items():
        print(f"mAP@{IOU} (classes present), {label}: {100 * value:.2f}")
    differences = (  # (what, version, reference, judged against the bar)
        ("registered - exact", REGISTERED, EXACT, True),
        ("sensed and registered - sensed in the colour camera", SENSED_REGISTERED, SENSED, True),
        ("noise floor: exact + 1 mm noise - exact", FLOOR, EXACT, False),
    )
    for what, a, b, judged in differences:
        difference = 100 * (scores[a] - scores[b])
        verdict = f" ({'PASS' if abs(difference) <= 1.0 else 'FAIL'}: bar 1 point)" if judged else ""
        print(f"{what}: {difference:+.2f} points{verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
