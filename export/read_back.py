"""A model file's weights read back into a trainable A3DNet: the export undone (a3d-finetune).

Why: a bundled model travels as its ONNX file alone, without the checkpoint it was exported from,
and fine-tuning it on a user's rooms needs its weights in torch. What a3d-export did to them is
undone where it can be and kept where it cannot:

- int8 weights and biases (QDQ: ``DequantizeLinear`` of an integer initializer) are dequantised,
  ``(q - zero_point) * scale`` per channel: the rounding stays, a fine start for fine-tuning;
- the trunks' BatchNorms were folded into their convs, and bn6/bn7 into fc6/fc7 (by the exporter):
  the network comes back plain (``net.trunk_norm`` off) with bn6/bn7 as identities, to be trained
  with their statistics fixed (``solver.frozen_norms``);
- fc6's input columns were permuted to the pooled maps' exported layout, which changed over
  a3d's versions ((c, y, x) before ``fold_pool_layout``, (y, x, c) with it, (y, c, x) after
  ``a3d.export.refold``): the layout whose network answers as the file does is the one taken;
- a bias of zeros is dropped by the exporter's optimiser, and comes back as zeros;
- the box heads answer raw deltas (``fold_target_stats``): the caller chooses target statistics
  and ``normalise_heads`` puts the heads back in their terms.

The class mean sizes and the training configuration come from the file's metadata.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from a3d.export.base import ExportError
from a3d.export.verify import Comparison, compare, synthetic_inputs
from a3d.runtime.network.model import DetectorModel, ModelMetadata
from a3d.train.config import TrainConfig
from a3d.train.dataset import TargetStats
from a3d.train.inference import TorchNetwork
from a3d.train.model import A3DNet

_POOLED_LAYOUTS = {"c, y, x": (0, 1, 2, 3), "y, x, c": (0, 2, 3, 1), "y, c, x": (0, 2, 1, 3)}


@dataclass(frozen=True)
class ReadBack:
    """A model file's network as torch weights (heads answering raw deltas), the training config
    to fine-tune it with, its metadata, the layout fc6 was found in and how closely the weights
    answer as the file does."""

    config: TrainConfig
    weights: dict[str, torch.Tensor]
    metadata: ModelMetadata
    layout: str
    agreement: Comparison


def read_back(path: str | os.PathLike, threads: int = 2) -> ReadBack:
    """The weights of model file ``path`` (module docstring); ExportError "PATH: ..." when the file
    is not an a3d network this can read."""
    path = Path(path)
    opened = DetectorModel.load(path, threads)  # ModelError for a file that is no a3d model
    config = _training_config(opened.metadata, path)
    values = dequantised_initializers(onnx.load(str(path)))
    net = A3DNet(config.net)
    weights, missing = {}, []
    for key, value in net.state_dict().items():
        found = values.get(f"net.{key}")
        if found is None and key.endswith(".bias"):  # a bias made by folding a BatchNorm into a Gemm
            found = values.get(f"net.{key.removesuffix('bias')}weight_bias")
        if found is None and key.split(".")[0] in ("bn6", "bn7"):
            found = _identity_norm(key, value, getattr(net, key.split(".")[0]).eps)
        elif found is None and key.endswith(".bias"):  # the exporter drops a bias of zeros
            found = np.zeros(tuple(value.shape))
        if found is None or tuple(found.shape) != tuple(value.shape):
            missing.append(key)
            continue
        weights[key] = torch.as_tensor(np.asarray(found), dtype=value.dtype)
    if missing:
        raise ExportError(f"{path}: no weight of the right shape for {missing[0]} (of {len(missing)})")
    inputs = [synthetic_inputs(opened.metadata.input_scale)]
    best = None
    for layout, axes in _POOLED_LAYOUTS.items():
        candidate = {**weights, "fc6.weight": _unpermute(weights["fc6.weight"], net, axes)}
        net.load_state_dict(candidate)
        agreement = compare(opened, TorchNetwork(net.eval(), TargetStats.identity()), inputs)
        if best is None or agreement.probs.max_abs < best[2].probs.max_abs:
            best = (layout, candidate, agreement)
    layout, weights, agreement = best
    return ReadBack(config, weights, opened.metadata, layout, agreement)


def dequantised_initializers(model: onnx.ModelProto) -> dict[str, np.ndarray]:
    """Every float initializer by name, and every integer initializer behind a DequantizeLinear
    dequantised, under its name without ``_quantized``."""
    initializers = {i.name: i for i in model.graph.initializer}
    values = {
        name: numpy_helper.to_array(i).astype(np.float64)
        for name, i in initializers.items()
        if i.data_type in (onnx.TensorProto.FLOAT, onnx.TensorProto.DOUBLE)
    }
    for node in model.graph.node:
        if node.op_type != "DequantizeLinear" or node.input[0] not in initializers:
            continue
        q, scale, zero = (
            numpy_helper.to_array(initializers[n]).astype(np.float64) if n in initializers else 0.0
            for n in [*node.input, ""][:3]
        )
        axis = next((a.i for a in node.attribute if a.name == "axis"), 1)
        if np.ndim(scale) == 1 and q.ndim > 1:  # per channel along ``axis``
            shape = [1] * q.ndim
            shape[axis] = -1
            scale, zero = np.reshape(scale, shape), np.reshape(zero, shape if np.ndim(zero) else ())
        values[node.input[0].removesuffix("_quantized")] = (q - zero) * scale
    return values


def normalise_heads(weights: dict[str, torch.Tensor], stats: TargetStats) -> dict[str, torch.Tensor]:
    """The box heads re-expressed for normalised targets: raw = n * std + mean, so W = W' / std and
    b = (b' - mean) / std row by row (fold_target_stats undone for ``stats``), in float64."""
    out = dict(weights)
    for layer, mean, std in (
        ("bbox_pred_3d", stats.mean3d, stats.std3d),
        ("bbox_pred_2d", stats.mean2d, stats.std2d),
    ):
        m, s = (torch.as_tensor(np.asarray(v, np.float64).reshape(-1)) for v in (mean, std))
        weight, bias = weights[f"{layer}.weight"], weights[f"{layer}.bias"]
        out[f"{layer}.weight"] = (weight.double() / s[:, None]).to(weight.dtype)
        out[f"{layer}.bias"] = ((bias.double() - m) / s).to(bias.dtype)
    return out


def _training_config(metadata: ModelMetadata, path: Path) -> TrainConfig:
    """The file's training configuration, its network plain (the BatchNorms are folded in)."""
    stored = metadata.provenance.get("training_config")
    if not isinstance(stored, dict) or "net" not in stored:
        raise ExportError(
            f"{path}: no training configuration in the model's provenance (not an a3d-export file?)"
        )
    config = TrainConfig.from_json(json.dumps(stored), f"{path} provenance.training_config")
    net = dataclasses.replace(config.net, trunk_norm=False, color_norm=None)
    if net.roi_pool != "align":
        raise ExportError(
            f"{path}: net.roi_pool={net.roi_pool!r}; only RoIAlign networks export and read back"
        )
    return dataclasses.replace(config, net=net)


def _identity_norm(key: str, value: torch.Tensor, eps: float) -> np.ndarray:
    """bn6/bn7 as the identity their fold into fc6/fc7 left: unit scale, zero shift and mean, and
    the variance that divides by exactly 1 (1 - eps)."""
    field = key.rsplit(".", 1)[-1]
    ones = np.ones(tuple(value.shape))
    return {"weight": ones, "running_var": ones * (1 - eps), "num_batches_tracked": np.zeros(())}.get(
        field, 0 * ones
    )


def _unpermute(weight: torch.Tensor, net: A3DNet, axes: tuple[int, ...]) -> torch.Tensor:
    """fc6's weight with its columns back in torch's (block, c, y, x) order from the layout ``axes``
    (of (block, c, y, x)) the file flattened the pooled maps in."""
    size, channels = net.config.pool_size, net.block_channels
    order = torch.arange(weight.shape[1]).reshape(-1, channels, size, size).permute(*axes).reshape(-1)
    restored = torch.empty_like(weight)
    restored[:, order] = weight
    return restored
