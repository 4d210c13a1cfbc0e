"""The Python API: ``Detector.load(model).detect(color, depth, intrinsics)`` (docs/api.md).

    from a3d.runtime import Detector
    det = Detector.load(threads=2)  # the bundled default, "real"; Detector.load("live"), or a file
    result = det.detect(color_rgb, depth_m, (fx, fy, cx, cy))   # or a 3x3 K, and R_tilt=...
    for d in result: print(d.class_name, d.score, d.box3d)      # the detections scoring >= 0.5
    image = result.draw(color_rgb)                              # boxes drawn, as the viewer shows them

It is the same pipeline a3d-run runs (a3d.runtime.pipeline) on arrays in memory; frame sources
(folders, data sets, bags, cameras) go through ``detect_frames``. Arrays are checked first
(a3d.runtime.sources.arrays): a bad one raises ``ArrayError`` (a ValueError) naming it.

Unlike a3d-run, which writes every detection down to the model's threshold (0 for the bundled
model: a3d-eval needs the whole precision-recall curve), ``detect`` returns the detections
scoring at least ``score_threshold``, by default ``SHOW_THRESHOLD`` (0.5, the viewer's: with
calibrated scores a detection there is as likely right as wrong); ``score_threshold=0`` returns
all of them, exactly a3d-run's line.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.classifier2d import Classifier2D
from a3d.runtime.detector2d import Detector2D
from a3d.runtime.frontend.working_size import WORKING_SIDE
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.models import model_path, pipeline_detector
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import FrameOutcome, FrontEnd, PipelineConfig, ProposalSource, detect, detect_frames
from a3d.runtime.postprocess.score_calibration import SHOW_THRESHOLD
from a3d.runtime.sources.arrays import IntrinsicsLike, frame_from_arrays, implausible_depth
from a3d.runtime.sources.base import FrameLoader, frame_loader
from a3d.runtime.structures.frame import Frame


class Detector:
    """An a3d model file with its pipeline settings, ready to detect."""

    def __init__(self, model: DetectorModel, config: PipelineConfig) -> None:
        self.model = model
        self.config = config
        self._warned_depth = False  # an implausible depth is said once per detector

    @classmethod
    def load(
        cls,
        model: str | os.PathLike | None = None,
        threads: int = 2,
        *,
        score_threshold: float | None = None,
        max_proposals: int | None = None,
        proposals: ProposalSource = "auto",
        front_end: FrontEnd = "model",
        raw_scores: bool = False,
        detector: str | os.PathLike | None = None,
        detector_names: str | os.PathLike | None = None,
        class_map: str | os.PathLike | None = None,
        classifier: str | os.PathLike | None = None,
        working_side: int | None = WORKING_SIDE,
    ) -> Detector:
        """Open and check a model: a bundled one by name (``"real"``, the default, or ``"live"``;
        a3d.runtime.models) or a model file (ModelError naming it if unusable); the settings default to
        the model's own (its metadata), each overridable as on a3d-run's command line
        (``score_threshold``: what the pipeline keeps, a3d-run's --score-threshold, below what
        ``detect`` returns; ``front_end="live"``: the faster proposals a3d-run uses for cameras;
        ``raw_scores``: the softmax scores, without the model's score calibration). ``detector``: a
        2D detector by name (``"yolox-nano"``) or ONNX file whose boxes join the network's RoIs,
        ``"none"`` for none; by default the one of a bundled pipeline (``"real"``), with its class
        names (``detector_names``) and class map (``class_map``) files where given
        (a3d.runtime.detector2d). ``classifier``: an image classifier by name (``"mobilenet-v2"``)
        or ONNX file whose view of the best own detections rescores them (a3d.runtime.classifier2d;
        off by default: docs/real-rooms.md has what it does to the scores). ``working_side``: a
        frame whose longer side is over it is brought down to it first, as the networks were trained
        (a3d.runtime.frontend.working_size); None or 0: every frame as it comes."""
        network = DetectorModel.load(model_path(model), threads=threads)
        config = PipelineConfig.from_metadata(
            network.metadata,
            proposal_source=proposals,
            max_proposals=max_proposals,
            min_score=score_threshold,
            front_end=front_end,
            raw_scores=raw_scores,
        )
        config = replace(config, working_side=working_side)
        chosen = pipeline_detector(model, detector, network.metadata.detector)
        if chosen is not None:
            names, mapping = _path(detector_names), _path(class_map)
            boxes = Detector2D.load(chosen, names=names, class_map=mapping)
            config = replace(config, detector=boxes)
        if classifier is not None:
            config = replace(config, classifier=Classifier2D.load(classifier, threads=threads))
        return cls(network, config)

    def detect(
        self,
        color: Any,
        depth: Any,
        intrinsics: IntrinsicsLike,
        R_tilt: Any = None,
        *,
        score_threshold: float = SHOW_THRESHOLD,
        depth_scale: float | None = None,
        name: str = "frame",
        pose: Any = None,
    ) -> FrameDetections:
        """Detections of one RGB-D frame scoring at least ``score_threshold`` (0: all; module
        docstring): ``color`` (H, W, 3) uint8 RGB, ``depth`` (H, W) metres (float) or uint16 in
        ``depth_scale`` metres (default millimetres), ``intrinsics`` (fx, fy, cx, cy) or 3x3,
        ``R_tilt`` the gravity rotation or None to estimate it; ``pose`` the 4x4 camera-to-world
        transform, carried into the result (its ``pose``) for mapping. Depth whose median is no
        room's (a wrong ``depth_scale``) is a warning, once per detector."""
        frame = frame_from_arrays(
            color, depth, intrinsics, R_tilt, depth_scale=depth_scale, name=name, pose=pose
        )
        integer = getattr(depth, "dtype", None) == np.uint16
        problem = None if self._warned_depth else implausible_depth(frame.depth, integer)
        if problem is not None:
            self._warned_depth = True
            warnings.warn(problem, stacklevel=2)
        return _above(detect(frame, self.model, self.config), score_threshold)

    def detect_frames(
        self,
        frames: Iterable[Frame | FrameLoader],
        *,
        overlap: bool = False,
        score_threshold: float = SHOW_THRESHOLD,
    ) -> Iterator[FrameOutcome]:
        """Detections of every frame of a source (``Frame``s or a source's loaders), in order, each
        scoring at least ``score_threshold`` as in ``detect``; a bad frame yields its one-line
        problem and the rest go on."""
        loaders = (item if isinstance(item, FrameLoader) else frame_loader(item) for item in frames)
        for outcome in detect_frames(loaders, self.model, self.config, overlap=overlap):
            if outcome.detections is not None:
                outcome = replace(outcome, detections=_above(outcome.detections, score_threshold))
            yield outcome


def _path(value: str | os.PathLike | None) -> Path | None:
    return None if value is None else Path(value)


def _above(result: FrameDetections, score_threshold: float) -> FrameDetections:
    """The detections scoring at least ``score_threshold`` (the result itself for 0)."""
    if not 0.0 <= score_threshold <= 1.0:
        raise ValueError(f"score_threshold: must be in [0, 1], got {score_threshold}")
    return result if score_threshold == 0 else result[result.scores >= score_threshold]
