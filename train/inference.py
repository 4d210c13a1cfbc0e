"""The pure-torch reference detector: the runtime's pipeline with the eager A3DNet as its network.

This is the path the ONNX runtime is compared against, so everything but the network call is the
runtime's own code, a3d.runtime.pipeline: reading, hole filling, gravity, proposals (or
``NAME.proposals.npz``), lifting, network inputs at the input scale, context boxes, per-class
top-k and 2D NMS, decoding, corners and the detections line. ``TorchNetwork`` fills the
pipeline's ``Detector`` slot: softmax scores and *raw* deltas, i.e. the network's normalised
deltas times the training target std plus mean (the ONNX export folds the same statistics into
its last layers). With ``inference.regress_3d`` off it answers zero 3D deltas, so every
detection keeps its initial box (lifted centre, class mean size, theta 0): the paper's
"-3dreg" ablation.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from a3d.runtime.evaluation.metric import EvalConfig, EvalResult, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.runtime.pipeline import PipelineConfig, detect, detect_frames
from a3d.runtime.sources.folder import FolderSource
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.runtime.structures.frame import Frame
from a3d.train.checkpoint import load_trained
from a3d.train.config import TrainConfig
from a3d.train.dataset import TargetStats
from a3d.train.model import A3DNet

HEAD_CHUNK = 512  # RoIs per head pass: bounds RoI pooling's memory at 2000 proposals


class TorchNetwork:
    """A3DNet behind the runtime pipeline's model interface (``run``), in eval mode, no gradients."""

    def __init__(self, model: A3DNet, stats: TargetStats, regress_3d: bool = True,
                 device: torch.device | str = "cpu") -> None:  # fmt: skip
        self.model = model
        self.stats = stats
        self.regress_3d = regress_3d
        self.device = torch.device(device)
        self.metadata = None  # the pipeline takes its settings from PipelineConfig instead

    def run(
        self, color: np.ndarray, depth: np.ndarray, rois: np.ndarray, context_rois: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(1, 3, h, w) inputs and (N, 4) RoIs in the input image's pixels -> softmax (N, 20),
        raw 3D deltas (N, 20, 7), raw 2D deltas (N, 20, 4)."""
        was_training = self.model.training
        self.model.eval()
        try:
            with torch.no_grad():
                logits, deltas3d, deltas2d = self._forward(color, depth, rois, context_rois)
        finally:
            self.model.train(was_training)
        probs = torch.softmax(logits.double(), dim=1).numpy()
        raw3d = self.stats.denormalise_3d(deltas3d.double().numpy().reshape(-1, NUM_OUTPUTS, 7))
        raw2d = self.stats.denormalise_2d(deltas2d.double().numpy().reshape(-1, NUM_OUTPUTS, 4))
        return probs, raw3d if self.regress_3d else np.zeros_like(raw3d), raw2d

    def _forward(self, color, depth, rois, context_rois) -> tuple[torch.Tensor, ...]:
        def batch_rois(boxes: np.ndarray) -> torch.Tensor:
            boxes = torch.from_numpy(np.asarray(boxes, np.float32).reshape(-1, 4))
            return torch.cat([torch.zeros(len(boxes), 1), boxes], dim=1).to(self.device)

        features = self.model.trunk_features(
            torch.from_numpy(np.asarray(color, np.float32)).to(self.device),
            torch.from_numpy(np.asarray(depth, np.float32)).to(self.device),
        )
        r, c = batch_rois(rois), batch_rois(context_rois)
        chunks = [slice(i, i + HEAD_CHUNK) for i in range(0, len(r), HEAD_CHUNK)]
        parts = [self.model.head(features, r[s], c[s]) for s in chunks]
        return tuple(torch.cat([p[k].float().cpu() for p in parts]) for k in range(3))


@dataclass
class TorchDetector:
    """A trained model ready for the runtime pipeline: network + pipeline settings."""

    network: TorchNetwork
    pipeline: PipelineConfig
    config: TrainConfig

    @classmethod
    def build(cls, model: A3DNet, config: TrainConfig, stats: TargetStats, mean_sizes: np.ndarray,
              device: torch.device | str = "cpu") -> TorchDetector:  # fmt: skip
        network = TorchNetwork(model, stats, config.inference.regress_3d, device)
        return cls(network, config.pipeline(mean_sizes), config)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, device: torch.device | str = "cpu",
                        config: TrainConfig | None = None) -> TorchDetector:  # fmt: skip
        """Load a training checkpoint; ``config`` replaces the stored one (e.g. inference settings)."""
        trained = load_trained(path, config)
        return cls.build(trained.net.to(device), trained.config, trained.stats, trained.mean_sizes, device)

    def detect(self, frame: Frame) -> FrameDetections:
        """Detections of one frame (README detections format, a3d.runtime.io.detections_io)."""
        return detect(frame, self.network, self.pipeline)


def write_folder_detections(
    detector: TorchDetector, folder: str | os.PathLike, out: str | os.PathLike, max_frames: int = 0
) -> tuple[list[FrameDetections], list[str]]:
    """Detections of the frames of ``folder`` written to ``out`` (JSON lines, as a3d-run writes
    them); a bad frame is skipped and reported as "PATH: problem" instead of stopping the run."""
    loaders = list(FolderSource(folder))
    loaders = loaders[:max_frames] if max_frames > 0 else loaders
    outcomes = detect_frames(loaders, detector.network, detector.pipeline)
    done, problems = [], []
    for outcome in outcomes:
        if outcome.detections is None:
            problems.append(outcome.problem)
        else:
            done.append(outcome.detections)
    write_detections(out, done)
    return done, problems


def validate(detector: TorchDetector, folder: str | os.PathLike, max_frames: int = 0) -> EvalResult:
    """The paper's mAP (a3d.runtime.evaluation.metric, as a3d-eval scores) on the annotated frames
    of ``folder``."""
    truth, _ = load_truth(Path(folder))
    source = FolderSource(folder)
    refs = [r for r in source.refs if r.name in truth]
    refs = refs[:max_frames] if max_frames > 0 else refs
    detections = {ref.name: detector.detect(source.read(ref)) for ref in refs}
    return evaluate({r.name: truth[r.name] for r in refs}, detections, EvalConfig())
