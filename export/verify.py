"""Checks of an exported model: onnx.checker, then ONNX Runtime against eager torch.

The reference is a3d.train.inference.TorchNetwork, the network of the pure-torch detector that
training validates with: the eager A3DNet (the checkpoint's, or its SVD copy) with the softmax and
the training target de-normalisation (``TargetStats.denormalise_3d/2d``) applied outside the
network, so a wrong fold of the statistics into the weights shows up as a difference. The model
side is the file as the runtime opens it (``a3d.runtime.network.model.DetectorModel``).

Differences are reported per output as the largest absolute difference and, for the deltas, that
difference relative to the largest reference magnitude (``rel``; element-wise ratios blow up at
deltas near zero). Tolerances (float32 graph vs float32 eager): class probabilities 1e-4
absolute, 3D and 2D deltas 1e-4 relative.

Inputs come from real frames through the runtime's own front end (a3d.runtime.pipeline.prepare
with the settings of the model's metadata: hole filling, proposals or ``NAME.proposals.npz``,
lifting, resizing, context boxes), or, without frames, from a seeded noise image of the resized
NYUv2 frame size with random boxes, some reaching past the border.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import onnx

from a3d.export.base import ExportError
from a3d.export.onnx_export import example_inputs
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import PipelineConfig, load_and_prepare
from a3d.runtime.sources.folder import FolderSource
from a3d.runtime.structures.geometry import NYU_CROP_SIZE
from a3d.train.inference import TorchNetwork

PROB_ATOL = 1e-4
DELTA_RTOL = 1e-4
SYNTHETIC_ROIS = 300


class VerificationError(ExportError):
    """The exported model differs from torch by more than the tolerances."""


@dataclass(frozen=True)
class NetworkInputs:
    """One image's network inputs: (1, 3, h, w) float32 colour and depth, (R, 4) float32 boxes."""

    name: str
    color: np.ndarray
    depth: np.ndarray
    rois: np.ndarray
    context_rois: np.ndarray


@dataclass(frozen=True)
class Difference:
    """Largest |got - want| and that over the largest |want|."""

    max_abs: float
    rel: float

    @classmethod
    def of(cls, got: np.ndarray, want: np.ndarray) -> Difference:
        if got.shape != want.shape:
            raise ExportError(f"output shape {got.shape} differs from the reference's {want.shape}")
        if got.size == 0:
            return cls(0.0, 0.0)
        diff = np.abs(np.asarray(got, np.float64) - want)
        max_abs = float(diff.max()) if np.all(np.isfinite(diff)) else math.inf
        return cls(max_abs, max_abs / max(float(np.abs(want).max()), 1e-30))


@dataclass(frozen=True)
class Comparison:
    """Differences of the three outputs (probs, deltas3d, deltas2d) over one or more inputs."""

    probs: Difference
    deltas3d: Difference
    deltas2d: Difference
    rois: int

    def outputs(self) -> dict[str, Difference]:
        return {"probs": self.probs, "deltas3d": self.deltas3d, "deltas2d": self.deltas2d}

    def within(self, prob_atol: float = PROB_ATOL, delta_rtol: float = DELTA_RTOL) -> bool:
        deltas_ok = max(self.deltas3d.rel, self.deltas2d.rel) <= delta_rtol
        return self.probs.max_abs <= prob_atol and deltas_ok

    def finite(self) -> bool:
        return all(math.isfinite(d.max_abs) for d in self.outputs().values())

    def worst(self, other: Comparison) -> Comparison:
        pairs = zip(self.outputs().values(), other.outputs().values(), strict=True)
        worst = [Difference(max(a.max_abs, b.max_abs), max(a.rel, b.rel)) for a, b in pairs]
        return Comparison(*worst, rois=self.rois + other.rois)

    def describe(self) -> str:
        d3, d2 = self.deltas3d, self.deltas2d
        return (
            f"probs max abs {self.probs.max_abs:.2e}, deltas3d max abs {d3.max_abs:.2e} (rel {d3.rel:.2e}), "
            f"deltas2d max abs {d2.max_abs:.2e} (rel {d2.rel:.2e}) over {self.rois} RoIs"
        )

    def to_dict(self) -> dict:
        return {
            "rois": self.rois,
            **{k: {"max_abs": d.max_abs, "rel": d.rel} for k, d in self.outputs().items()},
        }


def check_graph(path: str | os.PathLike) -> None:
    """onnx.checker with full shape inference; ExportError "PATH: ..." on failure."""
    try:
        onnx.checker.check_model(str(path), full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError) as e:
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise ExportError(f"{path}: onnx.checker refuses the exported graph ({first})") from None


def compare(model: DetectorModel, reference: TorchNetwork, inputs: list[NetworkInputs]) -> Comparison:
    """The worst differences between the model file and the eager reference over ``inputs``."""
    result = None
    for item in inputs:
        feeds = (item.color, item.depth, item.rois, item.context_rois)
        pairs = zip(model.run(*feeds), reference.run(*feeds), strict=True)
        one = Comparison(*(Difference.of(got, want) for got, want in pairs), rois=len(item.rois))
        result = one if result is None else result.worst(one)
    if result is None:
        raise ExportError("no verification inputs (no frame with a usable proposal)")
    return result


def folder_inputs(folder: str | os.PathLike, pipeline: PipelineConfig, limit: int) -> Iterator[NetworkInputs]:
    """The network inputs of the first ``limit`` frames of a frame folder (README "Frame format")
    that have at least one usable proposal, from the runtime's own front end."""
    for loader in itertools.islice(FolderSource(folder), limit):
        p = load_and_prepare(loader, pipeline)
        if len(p.rois):
            yield NetworkInputs(loader.name, p.color_input, p.depth_input, p.rois, p.context_rois)


def synthetic_inputs(input_scale: float, rois: int = SYNTHETIC_ROIS, seed: int = 0) -> NetworkInputs:
    """A seeded noise image of the resized NYUv2 frame size and random boxes (some past the border)."""
    height, width = (max(1, round(n * input_scale)) for n in NYU_CROP_SIZE)
    tensors = (t.numpy() for t in example_inputs(height, width, rois, seed))
    return NetworkInputs("synthetic", *tensors)
