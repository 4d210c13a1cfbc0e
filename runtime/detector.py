"""The Python API: ``Detector.load(model).detect(color, depth, intrinsics)``.

    from a3d.runtime import Detector
    det = Detector.load("samples/model.onnx", threads=2)
    result = det.detect(color_rgb, depth_m, (fx, fy, cx, cy))   # or a 3x3 K, and R_tilt=...
    result.classes, result.scores, result.boxes3d                # per detection
    print(result.to_json())                                     # exactly a3d-run's line

It is the same pipeline a3d-run runs (a3d.runtime.pipeline) on arrays in memory; frame sources
(folders, data sets, bags, cameras) go through ``detect_frames``. Arrays are checked first
(a3d.runtime.sources.arrays): a bad one raises ``ArrayError`` (a ValueError) naming it.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from typing import Any

from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import FrameOutcome, FrontEnd, PipelineConfig, ProposalSource, detect, detect_frames
from a3d.runtime.sources.arrays import IntrinsicsLike, frame_from_arrays
from a3d.runtime.sources.base import FrameLoader, frame_loader
from a3d.runtime.structures.frame import Frame


class Detector:
    """An a3d model file with its pipeline settings, ready to detect."""

    def __init__(self, model: DetectorModel, config: PipelineConfig) -> None:
        self.model = model
        self.config = config

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        threads: int = 2,
        *,
        score_threshold: float | None = None,
        max_proposals: int | None = None,
        proposals: ProposalSource = "auto",
        front_end: FrontEnd = "model",
        raw_scores: bool = False,
    ) -> Detector:
        """Open and check a model file (ModelError naming it if unusable); the settings default to
        the model's own (its metadata), each overridable as on a3d-run's command line
        (``front_end="live"``: the faster proposals a3d-run uses for cameras; ``raw_scores``: the
        softmax scores, without the model's score calibration)."""
        model = DetectorModel.load(path, threads=threads)
        config = PipelineConfig.from_metadata(
            model.metadata,
            proposal_source=proposals,
            max_proposals=max_proposals,
            min_score=score_threshold,
            front_end=front_end,
            raw_scores=raw_scores,
        )
        return cls(model, config)

    def detect(
        self,
        color: Any,
        depth: Any,
        intrinsics: IntrinsicsLike,
        R_tilt: Any = None,
        *,
        depth_scale: float | None = None,
        name: str = "frame",
        pose: Any = None,
    ) -> FrameDetections:
        """Detections of one RGB-D frame: ``color`` (H, W, 3) uint8 RGB, ``depth`` (H, W) metres
        (float) or uint16 in ``depth_scale`` metres (default millimetres), ``intrinsics``
        (fx, fy, cx, cy) or 3x3, ``R_tilt`` the gravity rotation or None to estimate it; ``pose``
        the 4x4 camera-to-world transform, carried into the result (its ``pose``) for mapping."""
        frame = frame_from_arrays(
            color, depth, intrinsics, R_tilt, depth_scale=depth_scale, name=name, pose=pose
        )
        return detect(frame, self.model, self.config)

    def detect_frames(
        self, frames: Iterable[Frame | FrameLoader], *, overlap: bool = False
    ) -> Iterator[FrameOutcome]:
        """Detections of every frame of a source (``Frame``s or a source's loaders), in order; a
        bad frame yields its one-line problem and the rest go on."""
        loaders = (item if isinstance(item, FrameLoader) else frame_loader(item) for item in frames)
        return detect_frames(loaders, self.model, self.config, overlap=overlap)
