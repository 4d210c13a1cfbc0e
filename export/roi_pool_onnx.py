"""The exported graph of RoI pooling's products: the same sum as training, with far less traffic.

Training pools with ``a3d.train.model.roi_pool.separable_pool``: the row weights of all RoIs
(R x 7, H) times the whole map (H, C x W), then the column weights per RoI. At the paper's sizes
(500 RoIs, 512 channels, a 27 x 36 map) the first product writes a 258 MB intermediate and costs
1.7 G multiply-adds per map, though each RoI's weights are zero outside its own few rows and
columns. The export swaps that product for the custom op ``a3d::separable_pool`` (same inputs,
the eager result in (y, x, c) order), whose ONNX translation here computes the sum on windows:

1. the RoIs are cut into ``POOL_CHUNKS`` chunks of consecutive rows (a3d.runtime.network.roi_order
   hands them over so that each chunk holds neighbours); below ``WINDOW_MIN_CHANNELS`` channels
   one chunk, i.e. the union of all;
2. each RoI's support (the first and last row and column where its weights are nonzero), and
   per chunk the union of its RoIs' supports, every chunk's bounds computed at once and handed
   out by ``Split``;
3. per chunk, the union window is sliced from the map in channels-last order and the training
   products run on it: the row weights (K x 7, h) times the window (h, w x C), then the column
   weights (K, 1, 7, w) times that (K, 7, w, C): (K, 7, 7, C), channels innermost, so the second
   product's columns are the channels (the weights outside the window are zero: the same sum);
4. the chunks concatenated in row order.

A chunk may be empty (fewer RoIs than chunks, or none): it slices a window of one RoI it does
not use and contributes no rows. Measured against the dense form and the other candidates in
``python -m bench.roi_pool_speed`` (docs/edge-speed.md "Where the head loses time"). The export
folds the (y, x, c) order into fc6's weights (``fold_pool_layout``) instead of transposing 50 MB
per map, and the int8 export quantises each chunk's product where it is made
(a3d.export.quantize), so the concatenations move bytes, not floats.
"""

from __future__ import annotations

import logging
import warnings
from collections import Counter

import numpy as np
import onnx
import torch
from onnx import TensorProto
from onnxscript import opset18 as op
from torch import nn

from a3d.export.base import ExportError
from a3d.runtime.network.roi_order import POOL_CHUNKS
from a3d.train.model.net import A3DNet
from a3d.train.model.roi_pool import pooling_rows, roi_weights, separable_pool

# Below this many channels (known when the export fixes them) the graph pools all RoIs as one
# chunk: the windows' nodes cost more than they save on a small map (the bundled model's 128
# channels on 14 x 18; docs/edge-speed.md "Where the head loses time").
WINDOW_MIN_CHANNELS = 256


@torch.library.custom_op("a3d::separable_pool", mutates_args=())
def separable_pool_op(rows: torch.Tensor, wy: torch.Tensor, wx: torch.Tensor) -> torch.Tensor:
    """``separable_pool`` as one op of the exported program, in (R, y, x, C) order, so that the
    export can translate it."""
    return separable_pool(rows, wy, wx).permute(0, 1, 3, 2).contiguous()


@separable_pool_op.register_fake
def _(rows: torch.Tensor, wy: torch.Tensor, wx: torch.Tensor) -> torch.Tensor:
    return rows.new_empty((wy.shape[0], wy.shape[1], wx.shape[1], rows.shape[1]))


def pool_chunks(channels: int | None) -> int:
    """The chunks the translation pools a map of ``channels`` channels in (None or symbolic: not
    fixed at export); a3d-export records it in the model's metadata for the runtime's order."""
    return 1 if isinstance(channels, int) and channels < WINDOW_MIN_CHANNELS else POOL_CHUNKS


def network_pool_chunks(net: A3DNet) -> int:
    """``pool_chunks`` of ``net``'s pooled maps: the fused channels, or the trunks' concatenated."""
    return pool_chunks(net.config.fuse_channels or sum(net.trunk_channels))


def _ints(*values: int):
    return op.Constant(value_ints=list(values))


def _column(value):
    """(n,) -> (n, 1)."""
    return op.Unsqueeze(value, _ints(1))


def _support(weights):
    """First row and end (last + 1) of each RoI's nonzero weights along the last axis of (R, P, L)
    as (R,) int64; an all-zero RoI gets [0, 1)."""
    nonzero = op.Cast(
        op.Greater(op.ReduceL1(weights, _ints(1), keepdims=0), op.Constant(value_float=0.0)),
        to=TensorProto.INT32,
    )
    first = op.ArgMax(nonzero, axis=1, keepdims=0)
    last = op.ArgMax(nonzero, axis=1, keepdims=0, select_last_index=1)
    found = op.Cast(op.ReduceMax(nonzero, _ints(1), keepdims=0), to=TensorProto.BOOL)
    return first, op.Where(
        found, op.Add(last, op.Constant(value_int=1)), op.Add(first, op.Constant(value_int=1))
    )


def _per_chunk(columns: list, chunks: int) -> list:
    """Row i of the (chunks, k) table whose columns are ``columns`` ((chunks,) each), as (k,) tensors."""
    flat = op.Reshape(op.Concat(*(_column(c) for c in columns), axis=1), _ints(-1))
    if chunks == 1:
        return [flat]
    return list(op.Split(flat, axis=0, num_outputs=chunks))


def separable_pool_onnx(rows, wy, wx):
    """The ONNX translation of ``a3d::separable_pool`` (module docstring): rows (B*H, C, W),
    wy (R, P, B*H), wx (R, P, W) -> (R, P, P, C)."""
    chunks = pool_chunks(rows.shape[1] if rows.shape is not None else None)
    count, size = op.Shape(wy, start=0, end=1), op.Shape(wy, start=1, end=2)
    channels = op.Shape(rows, start=1, end=2)
    cells = op.Reshape(op.Transpose(rows, perm=[0, 2, 1]), _ints(0, -1))  # (B*H, W * C), channels last
    bounds = op.Div(op.Mul(count, _ints(*range(chunks + 1))), _ints(chunks))
    starts, ends = op.Slice(bounds, _ints(0), _ints(chunks)), op.Slice(bounds, _ints(1), _ints(chunks + 1))
    longest = op.Max(op.Div(op.Add(count, _ints(chunks - 1)), _ints(chunks)), _ints(1))
    steps = op.Range(op.Constant(value_int=0), op.Squeeze(longest, _ints(0)), op.Constant(value_int=1))
    # Each chunk's RoIs (repeating its last); an empty chunk's, its predecessor's last RoI, or
    # for the first chunk (index -1) a dummy support of one cell appended after the RoIs'.
    members = op.Min(op.Add(_column(starts), op.Unsqueeze(steps, _ints(0))), _column(op.Sub(ends, _ints(1))))
    union = []  # low y, high y, low x, high x per chunk, (chunks,) each
    for weights in (wy, wx):
        first, end = _support(weights)
        first, end = op.Concat(first, _ints(0), axis=0), op.Concat(end, _ints(1), axis=0)
        union.append(op.ReduceMin(op.Gather(first, members), _ints(1), keepdims=0))
        union.append(op.ReduceMax(op.Gather(end, members), _ints(1), keepdims=0))
    low_y, high_y, low_x, high_x = union
    # windows as (h, w * C) slices of cells, row weights as (K * P, h) slices of wy's (R * P, B*H)
    window_low = _per_chunk([low_y, op.Mul(low_x, channels)], chunks)
    window_high = _per_chunk([high_y, op.Mul(high_x, channels)], chunks)
    row_low = _per_chunk([op.Mul(starts, size), low_y], chunks)
    row_high = _per_chunk([op.Mul(ends, size), high_y], chunks)
    row_weights_all = op.Flatten(wy, axis=2)
    column_low, column_high = _per_chunk([starts, low_x], chunks), _per_chunk([ends, high_x], chunks)
    fill = op.Expand(_ints(1), _ints(chunks))
    shapes = _per_chunk(  # (K, P, w, C) with no -1, so that an empty chunk reshapes too
        [op.Sub(ends, starts), op.Mul(fill, size), op.Sub(high_x, low_x), op.Mul(fill, channels)], chunks
    )
    columns = op.Unsqueeze(wx, _ints(1))  # (R, 1, P, W)
    pieces = []
    for i in range(chunks):
        window = op.Slice(cells, window_low[i], window_high[i], _ints(0, 1))  # (h, w * C)
        row_weights = op.Slice(row_weights_all, row_low[i], row_high[i], _ints(0, 1))  # (K * P, h)
        by_rows = op.MatMul(row_weights, window)  # (K * P, w * C)
        column_weights = op.Slice(columns, column_low[i], column_high[i], _ints(0, 3))  # (K, 1, P, w)
        pieces.append(op.MatMul(column_weights, op.Reshape(by_rows, shapes[i])))  # (K, P, P, C)
    return op.Concat(*pieces, axis=0) if chunks > 1 else pieces[0]


TRANSLATIONS = {torch.ops.a3d.separable_pool.default: separable_pool_onnx}


def join_maps_by_chunk(model: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` (changed in place) with fc6's input, the pooled maps (RoI, context) flattened and
    joined side by side, each map the join of its chunks, rebuilt as each chunk's pieces of both
    maps joined side by side (while they are in cache), then one join of the chunks and one
    flattening: the same rows. The two maps' chunk i holds the same RoIs (``separable_pool_onnx``
    cuts every map's rows alike). Measured: docs/edge-speed.md "Signed windows, an order for the
    intermediate"."""
    graph = model.graph
    producers = {out: n for n in graph.node for out in n.output}
    readers = Counter(name for n in graph.node for name in n.input)
    shapes = {
        i.name: onnx.numpy_helper.to_array(i) for i in graph.initializer if i.data_type == TensorProto.INT64
    }

    def chunked_map(name: str) -> tuple[onnx.NodeProto, onnx.NodeProto, int] | None:
        """(the (R, X) flattening, the join of its chunks, X) behind ``name``, each read once, or None."""
        flat = producers.get(name)
        shape = shapes.get(flat.input[1]) if flat is not None and flat.op_type == "Reshape" else None
        if shape is None or len(shape) != 2 or shape[0] != -1 or readers[name] != 1:
            return None
        chunks = producers.get(flat.input[0])
        if chunks is None or chunks.op_type != "Concat" or _axis(chunks) != 0 or readers[flat.input[0]] != 1:
            return None
        return flat, chunks, int(shape[1])

    replaced: set[str] = set()  # the flattenings' shapes
    gone: set[str] = set()  # the maps' tensors before the join
    for join in [n for n in graph.node if n.op_type == "Concat" and len(n.input) > 1]:
        if _axis(join) not in (1, -1):
            continue
        maps = [chunked_map(name) for name in join.input]
        if (
            any(m is None for m in maps)
            or len({(len(m[1].input), m[2]) for m in maps}) != 1  # alike chunks and rows
            or len(maps[0][1].input) < 2
        ):
            continue
        at = list(graph.node).index(join)
        pairs = []
        for i, pieces in enumerate(zip(*(m[1].input for m in maps), strict=True)):
            pairs.append(f"{join.name}/chunk{i}")
            graph.node.insert(at + i, onnx.helper.make_node(
                "Concat", list(pieces), [pairs[-1]], axis=1, name=pairs[-1]))  # fmt: skip
        width = f"{join.name}/row_shape"
        graph.initializer.append(
            onnx.numpy_helper.from_array(np.array([-1, sum(m[2] for m in maps)], np.int64), width)
        )
        graph.node.insert(at + len(pairs), onnx.helper.make_node(
            "Concat", pairs, [f"{join.name}/chunks"], axis=0, name=f"{join.name}/chunks"))  # fmt: skip
        graph.node.insert(at + len(pairs) + 1, onnx.helper.make_node(
            "Reshape", [f"{join.name}/chunks", width], list(join.output),
            name=f"{join.name}/rows"))  # fmt: skip
        for node in [join, *(n for m in maps for n in m[:2])]:
            graph.node.remove(node)
        replaced |= {m[0].input[1] for m in maps}
        gone |= {m[0].output[0] for m in maps} | {m[1].output[0] for m in maps}
    used = {name for n in graph.node for name in n.input}
    kept = [i for i in graph.initializer if i.name in used or i.name not in replaced]
    del graph.initializer[:]
    graph.initializer.extend(kept)
    infos = [v for v in graph.value_info if v.name not in gone]
    del graph.value_info[:]
    graph.value_info.extend(infos)
    return model


def _axis(node: onnx.NodeProto) -> int | None:
    return next((a.i for a in node.attribute if a.name == "axis"), None)


def _first_linear(layer: nn.Module) -> nn.Linear:
    """fc6 itself, or the first factor of its SVD (a3d.export.svd)."""
    return (
        layer
        if isinstance(layer, nn.Linear)
        else next(m for m in layer.modules() if isinstance(m, nn.Linear))
    )


def fold_pool_layout(folded: A3DNet) -> A3DNet:
    """``folded`` itself (changed in place), its RoI pooling now ``a3d::separable_pool`` flattened in
    that op's (y, x, c) order and fc6's input columns permuted from (c, y, x) to match: the same
    outputs without a 50 MB transpose per map. Max RoI pooling (the training-only ablation) is refused."""
    if folded.config.roi_pool != "align":
        raise ExportError(f"net.roi_pool={folded.config.roi_pool!r}: only RoIAlign networks are exported")
    folded.pool_product = separable_pool_op
    fc6 = _first_linear(folded.fc6)
    size = folded.config.pool_size
    boxes = 2 if folded.config.use_context else 1
    channels = fc6.in_features // (boxes * size * size)  # of one pooled map (both trunks' without fusion)
    index = torch.arange(fc6.in_features).reshape(-1, channels, size, size).permute(0, 2, 3, 1).reshape(-1)
    with torch.no_grad():
        fc6.weight.copy_(fc6.weight[:, index])
    return folded


class RoiAlignGraph(nn.Module):
    """forward(features (B, C, H, W), rois (R, 5)) -> (R, P, P, C): roi_align as the export writes
    it (the weights from training's code, the products through ``a3d::separable_pool``), for
    bench.roi_pool_speed and the parity tests."""

    def __init__(
        self, output_size: int = 7, spatial_scale: float = 1.0 / 16.0, sampling_ratio: int = 2
    ) -> None:
        super().__init__()
        self.arguments = (output_size, spatial_scale, sampling_ratio)

    def forward(self, features: torch.Tensor, rois: torch.Tensor) -> torch.Tensor:
        return separable_pool_op(pooling_rows(features), *roi_weights(features, rois, *self.arguments))


def export_roi_align(
    path: str, features: torch.Tensor, rois: torch.Tensor, opset: int = 18, fixed_channels: bool = False
) -> None:
    """Export ``RoiAlignGraph`` to ``path`` with the batch, map size, RoI count and (unless
    ``fixed_channels``, as a3d-export fixes them) the channel count dynamic."""
    dims = {0: torch.export.Dim("batch"), 2: torch.export.Dim("height"), 3: torch.export.Dim("width")}
    if not fixed_channels:
        dims[1] = torch.export.Dim("channels")
    dynamo_export(
        RoiAlignGraph(),
        (features, rois),
        path,
        input_names=["features", "rois"],
        output_names=["pooled"],
        opset=opset,
        dynamic_shapes={"features": dims, "rois": {0: torch.export.Dim("rois")}},
    )


def dynamo_export(
    module: nn.Module,
    args: tuple,
    path: str,
    *,
    input_names: list[str],
    output_names: list[str],
    dynamic_shapes: dict,
    opset: int,
) -> None:
    """torch.onnx.export (dynamo) of ``module`` with a3d's translations (TRANSLATIONS), the weights
    inline, and the exporter's chatter silenced: its registry's "torchvision is not installed" for
    every torchvision op, its deprecation and dynamic-shape warnings."""
    registry_log = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registry_log.level
    registry_log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            torch.onnx.export(
                module,
                args,
                path,
                input_names=input_names,
                output_names=output_names,
                dynamic_shapes=dynamic_shapes,
                custom_translation_table=TRANSLATIONS,
                opset_version=opset,
                dynamo=True,
                external_data=False,
                verbose=False,
            )
    finally:
        registry_log.setLevel(level)
