"""A3DNet -> the runtime's ONNX graph (the a3d.runtime.network.model contract) and the model file.

``RuntimeGraph`` wraps a trained A3DNet into what the runtime runs: one image, (R, 4) RoIs (the
batch index column of zeros is added inside), softmax inside, outputs reshaped to (R, 20, 7) and
(R, 20, 4). The training target normalisation is folded into the box heads' weights
(``fold_target_stats``), as the authors' release does at save time (docs/conventions.md "Regression
targets"), so the graph answers raw deltas for box_coder.decode_3d / decode_2d.

Export uses the torch.onnx dynamo exporter as tests/test_model_onnx.py does (weights inside the
file: external_data=False; opset >= 18, the lowest it implements; IR version <= 13 for ONNX
Runtime, docs/platform.md "ONNX / ONNX Runtime pitfalls"), with the image size and the RoI count dynamic.
"""

from __future__ import annotations

import copy
import dataclasses
import os
from pathlib import Path

import onnx
import torch
from torch import nn

from a3d.export.base import MAX_IR_VERSION, MIN_OPSET, ExportError
from a3d.export.roi_pool_onnx import dynamo_export, fold_pool_layout, join_maps_by_chunk
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.network.model import INPUT_NAMES, METADATA_KEY, OUTPUT_NAMES, ModelMetadata, content_digest
from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.train.dataset import TargetStats
from a3d.train.model.net import BOX2D_SIZE, A3DNet

EXAMPLE_SIZE = (64, 80)  # (h, w) of the tracing example; the exported graph takes any size


class RuntimeGraph(nn.Module):
    """forward(color (1,3,h,w), depth (1,3,h,w), rois (R,4), context_rois (R,4))
    -> (class_probs (R,20), deltas3d (R,20,7), deltas2d (R,20,4)), deltas raw (de-normalised).

    ``regress_3d=False`` (the training config's "-3dreg" ablation) answers zero 3D deltas, which
    decode to the initial boxes, as a3d.train.inference.TorchNetwork does.
    """

    def __init__(self, net: A3DNet, stats: TargetStats, regress_3d: bool = True) -> None:
        super().__init__()
        self.net = fold_pool_layout(fold_target_stats(net, stats, regress_3d))

    def forward(
        self, color: torch.Tensor, depth: torch.Tensor, rois: torch.Tensor, context_rois: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        image = torch.zeros_like(rois[:, :1])  # every RoI is on image 0 of a batch of one
        logits, deltas3d, deltas2d = self.net(
            color, depth, torch.cat([image, rois], dim=1), torch.cat([image, context_rois], dim=1)
        )
        return (
            torch.softmax(logits, dim=1),
            deltas3d.reshape(-1, NUM_OUTPUTS, BOX_DIM),
            deltas2d.reshape(-1, NUM_OUTPUTS, BOX2D_SIZE),
        )


def fold_target_stats(net: A3DNet, stats: TargetStats, regress_3d: bool = True) -> A3DNet:
    """An eval-mode copy of ``net`` whose box heads answer raw deltas (and trunk BatchNorms folded).

    The network predicts normalised deltas n = W x + b, and raw = n * std + mean per class and
    coordinate (output row k * 7 + j for class k, coordinate j); so W' = std * W (row-wise) and
    b' = std * b + mean give raw = W' x + b'. Computed in float64, stored in the layer's dtype.
    Without ``regress_3d`` the 3D head becomes zero (std = mean = 0).
    """
    folded = copy.deepcopy(net).eval()
    for trunk in (folded.color_trunk, folded.depth_trunk):
        if trunk is not None:
            trunk.fold_batch_norms()
    keep = 1.0 if regress_3d else 0.0
    with torch.no_grad():
        for layer, mean, std in (
            (folded.bbox_pred_3d, keep * stats.mean3d, keep * stats.std3d),
            (folded.bbox_pred_2d, stats.mean2d, stats.std2d),
        ):
            m = torch.as_tensor(mean, dtype=torch.float64).reshape(-1)
            s = torch.as_tensor(std, dtype=torch.float64).reshape(-1)
            layer.weight.copy_(layer.weight.double() * s[:, None])
            layer.bias.copy_(layer.bias.double() * s + m)
    return folded


def example_inputs(height: int, width: int, count: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Distinct random network inputs (the exporter merges aliased example tensors into one input)."""
    gen = torch.Generator().manual_seed(seed)
    color = torch.randn(1, 3, height, width, generator=gen) * 50
    depth = torch.randn(1, 3, height, width, generator=gen) * 50
    boxes = []
    for _ in range(2):
        corner = torch.rand(count, 2, generator=gen) * torch.tensor([width, height]) - 0.5
        size = torch.rand(count, 2, generator=gen) * torch.tensor([width, height]) / 2 + 1
        boxes.append(torch.cat([corner, corner + size], dim=1))
    return color, depth, boxes[0], boxes[1]


def export_graph(graph: RuntimeGraph, path: str | os.PathLike, opset: int = MIN_OPSET) -> onnx.ModelProto:
    """Trace ``graph`` to ONNX at ``path`` (plain graph, no a3d metadata yet) and return it."""
    if opset < MIN_OPSET:
        raise ExportError(f"--opset {opset}: the exporter supports opset {MIN_OPSET} or newer")
    graph = graph.eval()
    image, count = {2: "height", 3: "width"}, {0: "rois"}
    dynamo_export(
        graph,
        example_inputs(*EXAMPLE_SIZE, count=5),
        str(path),
        input_names=list(INPUT_NAMES),
        output_names=list(OUTPUT_NAMES),
        opset=opset,
        dynamic_shapes={"color": image, "depth": image, "rois": count, "context_rois": count},
    )
    model = onnx.load(str(path))
    got = next((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), None)
    if got != opset:
        raise ExportError(f"--opset {opset}: the exporter wrote opset {got}")
    model.ir_version = min(model.ir_version, MAX_IR_VERSION)
    onnx.save(join_maps_by_chunk(model), str(path))
    return model


def save_model(model: onnx.ModelProto, metadata: ModelMetadata, path: str | os.PathLike) -> ModelMetadata:
    """Write ``model`` with ``metadata`` (its content digest filled in) atomically to ``path``.

    Sets the a3d entry of ``model.metadata_props`` in place (other entries are kept) and returns
    the metadata written.
    """
    others = {p.key: p.value for p in model.metadata_props if p.key != METADATA_KEY}
    onnx.helper.set_model_props(model, others)
    digest = content_digest(model.SerializeToString(), str(path))
    metadata = dataclasses.replace(metadata, content_sha256=digest)
    model.metadata_props.add(key=METADATA_KEY, value=metadata.to_json())
    atomic_write_bytes(Path(path), model.SerializeToString())
    return metadata
