"""Tiny frame folders and a fake model for the runtime's tests (a3d-run's pipeline, CLI, robustness).

``scene`` draws a wall, a floor and a few coloured boxes at 72 x 96 with sensor holes: frames this
small keep a run over many frames, orders and failure modes fast, and the fixed layout lets a test
pin the estimated-gravity case (``write_scene_folder(..., estimated_gravity=...)``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from a3d.runtime.frontend.proposals import ProposalConfig
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.network.model import SCHEMA_VERSION, ModelMetadata
from a3d.runtime.network.preprocess import COLOR_MEAN_BGR, DEPTH_MEAN
from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES, NUM_OUTPUTS
from a3d.runtime.structures.geometry import Intrinsics, rtilt_from_pitch_roll

H, W = 72, 96
K = Intrinsics(fx=80.0, fy=80.0, cx=47.5, cy=35.5)
MEAN_SIZES = np.column_stack([np.linspace(0.5, 2.0, NUM_CLASSES), np.linspace(0.4, 1.0, NUM_CLASSES),
                              np.linspace(0.3, 1.5, NUM_CLASSES)])  # fmt: skip


def fake_metadata(**changes) -> ModelMetadata:
    """Metadata of a small CPU model: half-scale input, at most 60 proposals."""
    values = dict(
        schema_version=SCHEMA_VERSION,
        classes=CLASSES,
        mean_sizes=MEAN_SIZES,
        color_mean_bgr=tuple(float(v) for v in COLOR_MEAN_BGR),
        depth_mean=float(DEPTH_MEAN),
        depth_truncation_m=10.0,
        input_scale=0.5,
        context_scale=1.5,
        min_score=0.0,
        nms_iou=0.3,
        top_k=100,
        proposals=ProposalConfig(max_proposals=60),
        content_sha256="0" * 64,
    )
    return ModelMetadata(**{**values, **changes})


class FakeModel:
    """DetectorModel's interface; each RoI's outputs are a fixed function of its two boxes only,
    so a frame's results do not depend on the other frames or on the run's order."""

    def __init__(self, metadata: ModelMetadata | None = None) -> None:
        self.metadata = metadata or fake_metadata()
        rng = np.random.default_rng(7)
        self.weights = [rng.normal(0, 0.05, (9, NUM_OUTPUTS * m)) for m in (1, 7, 4)]
        self.calls = 0

    def run(self, color, depth, rois, context_rois):
        assert color.shape[:2] == (1, 3) and color.shape == depth.shape and color.dtype == np.float32
        assert rois.dtype == np.float32 and rois.shape == context_rois.shape and rois.shape[1] == 4
        self.calls += 1
        n = len(rois)
        features = np.hstack([rois, context_rois, np.ones((n, 1), np.float32)]).astype(np.float64)
        logits, d3, d2 = (np.sin(features @ w) for w in self.weights)
        probs = np.exp(4 * logits)
        probs /= probs.sum(axis=1, keepdims=True)
        return (probs.astype(np.float32), (0.2 * d3).reshape(n, NUM_OUTPUTS, 7).astype(np.float32),
                (0.2 * d2).reshape(n, NUM_OUTPUTS, 4).astype(np.float32))  # fmt: skip


def scene(seed: int, height: int = H, width: int = W) -> tuple[np.ndarray, np.ndarray]:
    """A wall with a floor and a few coloured boxes in front: (colour uint8 BGR, depth metres with holes)."""
    rng = np.random.default_rng(seed)
    v = np.arange(height)[:, None].repeat(width, axis=1)
    depth = np.full((height, width), 4.0, np.float32)
    floor = v > height * 0.6
    depth[floor] = (4.0 * (height * 0.6) / v[floor]).astype(np.float32) + 0.5
    color = np.empty((height, width, 3), np.uint8)
    color[:] = (150, 160, 170)
    color[floor] = (60, 90, 120)
    for _ in range(3):
        h, w = rng.integers(height // 6, height // 2), rng.integers(width // 8, width // 3)
        y, x = rng.integers(0, height - h), rng.integers(0, width - w)
        depth[y : y + h, x : x + w] = rng.uniform(1.5, 3.5)
        color[y : y + h, x : x + w] = rng.integers(0, 255, 3)
    color = np.clip(color + rng.normal(0, 3, color.shape), 0, 255).astype(np.uint8)
    depth[rng.random((height, width)) < 0.03] = 0.0  # sensor holes
    return color, depth


def write_scene_folder(folder: Path, names: list[str], *, estimated_gravity: tuple[str, ...] = ()) -> Path:
    """Frames NAME (seed = index) with folder intrinsics; R_tilt given except for ``estimated_gravity``."""
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder, K)
    for i, name in enumerate(names):
        color, depth = scene(i)
        R = (
            None
            if name in estimated_gravity
            else rtilt_from_pitch_roll(np.radians(-8.0 - i), np.radians(1.5))
        )
        write_frame(folder, name, color, depth, R_tilt=R)
    return folder


def without_timing(det: FrameDetections) -> dict:
    """A line's content as comparable arrays (timing left out: it is the only thing that varies)."""
    return {
        "frame": det.frame, "R_tilt": det.R_tilt, "class_ids": det.class_ids, "scores": det.scores,
        "boxes2d": det.boxes2d, "boxes3d": det.boxes3d, "corners": det.corners, "amodal": det.boxes2d_amodal,
    }  # fmt: skip


def assert_same_detections(a: FrameDetections, b: FrameDetections, rounded: bool = False) -> None:
    """Equal lines; ``rounded``: one went through the file, which keeps 1e-6 m and 1e-4 pixel."""
    da, db = without_timing(a), without_timing(b)
    assert da["frame"] == db["frame"]
    for key in da:
        if key != "frame":
            atol = (5e-5 if key in ("boxes2d", "amodal") else 5e-7) if rounded else 0.0
            np.testing.assert_allclose(da[key], db[key], rtol=0, atol=atol, err_msg=key)
