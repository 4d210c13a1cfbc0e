"""The exported graph of RoI pooling's products: the same sum as training, with far less traffic.

Training pools with ``a3d.train.model.roi_pool.separable_pool``: the row weights of all RoIs
(R x 7, H) times the whole map (H, C x W), then the column weights per RoI. At the paper's sizes
(500 RoIs, 512 channels, a 27 x 36 map) the first product writes a 258 MB intermediate and costs
1.7 G multiply-adds per map, though each RoI's weights are zero outside its own few rows and
columns. The export swaps that product for the custom op ``a3d::separable_pool`` (same inputs,
same eager result), whose ONNX translation here computes the sum on windows:

1. each RoI's support: the first and last row and column where its weights are nonzero;
2. the RoIs sorted by a Morton code of their support's corners (RoIs of similar position and
   size end up next to each other) and cut into ``CHUNKS`` equal chunks;
3. per chunk, the union of its RoIs' supports is sliced from the map and the training products
   run on that window only (the weights outside it are zero, so the sum is the same);
4. the chunks concatenated and the rows put back in the input order.

Measured against the dense form and the other candidates in ``python -m bench.roi_pool_speed``
(docs/edge-speed.md "Where the head loses time"). The output keeps separable_pool's (y, c, x)
layout; the export folds that order into fc6's weights (``fold_pool_layout``) instead of
transposing 50 MB per map. A dummy all-zero RoI is appended so that a call with no RoIs keeps
every shape non-empty; its row is dropped at the end.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
import torch
from onnx import TensorProto, numpy_helper
from onnxscript import opset18 as op
from torch import nn

from a3d.export.base import ExportError
from a3d.train.model.net import A3DNet
from a3d.train.model.roi_pool import pooling_rows, roi_weights, separable_pool

CHUNKS = 32
# Below this many channels (known when the export fixes them) the graph keeps the two dense
# products: the windows' ~700 small nodes cost more than they save on a small map (the bundled
# model's 128 channels on 14 x 18: 16.8 ms against 6.7 ms dense; the paper's 512 on 27 x 36:
# 33 against 44 ms; docs/edge-speed.md "Where the head loses time").
WINDOW_MIN_CHANNELS = 256
# Corners up to 256 cells (4096 pixels at stride 16); beyond, the sort is coarser, never wrong.
MORTON_BITS = 8


@torch.library.custom_op("a3d::separable_pool", mutates_args=())
def separable_pool_op(rows: torch.Tensor, wy: torch.Tensor, wx: torch.Tensor) -> torch.Tensor:
    """``separable_pool`` as one op of the exported program, so that the export can translate it."""
    return separable_pool(rows, wy, wx).clone()


@separable_pool_op.register_fake
def _(rows: torch.Tensor, wy: torch.Tensor, wx: torch.Tensor) -> torch.Tensor:
    return rows.new_empty((wy.shape[0], wy.shape[1], rows.shape[1], wx.shape[1]))


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


def _morton_order(corners, count):
    """Indices sorting (R, 4) int64 corners by their interleaved bits (a Z-order curve in 4-D)."""
    powers = op.Constant(value_ints=[1 << b for b in range(MORTON_BITS)])
    bits = op.Mod(op.Div(op.Unsqueeze(corners, _ints(2)), powers), op.Constant(value_int=2))  # (R, 4, bits)
    place = (1 << (4 * np.arange(MORTON_BITS)[None, :] + np.arange(4)[:, None])).astype(np.int64)
    weights = op.Constant(value=numpy_helper.from_array(place))
    code = op.ReduceSum(op.Mul(bits, weights), _ints(1, 2), keepdims=0)
    return op.TopK(op.Neg(code), count, largest=1, sorted=1)[1]


def _dense_products(rows, wy, wx):
    """Training's two products as they are (``separable_pool``), without the final transpose."""
    count, size = op.Shape(wy, start=0, end=1), op.Shape(wy, start=1, end=2)
    stacked, channels = op.Shape(wy, start=2, end=3), op.Shape(rows, start=1, end=2)
    by_rows = op.MatMul(
        op.Reshape(wy, op.Concat(op.Mul(count, size), stacked, axis=0)),
        op.Reshape(rows, op.Concat(stacked, _ints(-1), axis=0)),
    )
    by_rows = op.Reshape(
        by_rows, op.Concat(count, op.Mul(size, channels), op.Shape(wx, start=2, end=3), axis=0)
    )
    pooled = op.MatMul(by_rows, op.Transpose(wx, perm=[0, 2, 1]))  # (R, P*C, P)
    return op.Reshape(pooled, op.Concat(count, size, channels, size, axis=0))


def separable_pool_onnx(rows, wy, wx):
    """The ONNX translation of ``a3d::separable_pool`` (module docstring): rows (B*H, C, W),
    wy (R, P, B*H), wx (R, P, W) -> (R, P, C, P); the dense products where the export fixes
    fewer than ``WINDOW_MIN_CHANNELS`` channels."""
    fixed = rows.shape[1] if rows.shape is not None else None
    if isinstance(fixed, int) and fixed < WINDOW_MIN_CHANNELS:
        return _dense_products(rows, wy, wx)
    count = op.Shape(wy, start=0, end=1)
    size = op.Shape(wy, start=1, end=2)
    channels = op.Shape(rows, start=1, end=2)
    one = _ints(1)
    wy = op.Concat(wy, op.ConstantOfShape(op.Concat(one, op.Shape(wy, start=1), axis=0)), axis=0)
    wx = op.Concat(wx, op.ConstantOfShape(op.Concat(one, op.Shape(wx, start=1), axis=0)), axis=0)
    total = op.Add(count, one)  # with the dummy RoI
    first_y, end_y = _support(wy)
    first_x, end_x = _support(wx)
    corners = op.Concat(*(_column(c) for c in (first_x, first_y, end_x, end_y)), axis=1)
    order = _morton_order(corners, total)
    per_chunk = op.Div(op.Add(total, _ints(CHUNKS - 1)), _ints(CHUNKS))  # (1,)
    padding = op.Sub(op.Mul(per_chunk, _ints(CHUNKS)), total)
    padded = op.Concat(order, op.Expand(op.Slice(order, _ints(-1), _ints(1 << 62)), padding), axis=0)
    grid = op.Reshape(padded, op.Concat(_ints(CHUNKS), per_chunk, axis=0))  # (n, K): chunk i's RoIs
    low_y = op.ReduceMin(op.Gather(first_y, grid), one, keepdims=0)  # (n,)
    high_y = op.ReduceMax(op.Gather(end_y, grid), one, keepdims=0)
    low_x = op.ReduceMin(op.Gather(first_x, grid), one, keepdims=0)
    high_x = op.ReduceMax(op.Gather(end_x, grid), one, keepdims=0)
    span_y, span_x = op.Sub(high_y, low_y), op.Sub(high_x, low_x)
    starts = op.Concat(_column(low_y), _column(low_x), axis=1)  # (n, 2)
    ends = op.Concat(_column(high_y), _column(high_x), axis=1)
    chunk_column = _ints(CHUNKS, 1)
    weight_shapes = op.Concat(op.Expand(op.Mul(per_chunk, size), chunk_column), _column(span_y), axis=1)
    window_shapes = op.Concat(_column(span_y), op.Expand(_ints(-1), chunk_column), axis=1)
    product_shapes = op.Concat(
        op.Expand(per_chunk, chunk_column),
        op.Expand(op.Mul(size, channels), chunk_column),
        _column(span_x),
        axis=1,
    )
    columns = op.Transpose(wx, perm=[0, 2, 1])  # (R + 1, W, P)
    pieces = []
    for i in range(CHUNKS):
        at = op.Constant(value_int=i)
        rois = op.Gather(grid, at)
        start, end = op.Gather(starts, at), op.Gather(ends, at)
        window = op.Slice(rows, start, end, _ints(0, 2))  # (h, C, w): the chunk's union window
        row_weights = op.Slice(
            op.Gather(wy, rois), op.Gather(_column(low_y), at), op.Gather(_column(high_y), at), _ints(2)
        )
        by_rows = op.MatMul(
            op.Reshape(row_weights, op.Gather(weight_shapes, at)),
            op.Reshape(window, op.Gather(window_shapes, at)),
        )
        by_rows = op.Reshape(by_rows, op.Gather(product_shapes, at))  # (K, P*C, w)
        column_weights = op.Slice(
            op.Gather(columns, rois), op.Gather(_column(low_x), at), op.Gather(_column(high_x), at), one
        )
        pieces.append(op.MatMul(by_rows, column_weights))  # (K, P*C, P)
    inverse = op.Slice(op.TopK(op.Neg(order), total, largest=1, sorted=1)[1], _ints(0), count)
    pooled = op.Gather(op.Concat(*pieces, axis=0), inverse)
    return op.Reshape(pooled, op.Concat(count, size, channels, size, axis=0))


TRANSLATIONS = {torch.ops.a3d.separable_pool.default: separable_pool_onnx}


def _first_linear(layer: nn.Module) -> nn.Linear:
    """fc6 itself, or the first factor of its SVD (a3d.export.svd)."""
    return (
        layer
        if isinstance(layer, nn.Linear)
        else next(m for m in layer.modules() if isinstance(m, nn.Linear))
    )


def fold_pool_layout(folded: A3DNet) -> A3DNet:
    """``folded`` itself (changed in place), its RoI pooling now ``a3d::separable_pool`` flattened in
    that op's (y, c, x) order and fc6's input columns permuted from (c, y, x) to match: the same
    outputs without a 50 MB transpose per map. Max RoI pooling (the training-only ablation) is refused."""
    if folded.config.roi_pool != "align":
        raise ExportError(f"net.roi_pool={folded.config.roi_pool!r}: only RoIAlign networks are exported")
    folded.pool_product = separable_pool_op
    fc6 = _first_linear(folded.fc6)
    size = folded.config.pool_size
    boxes = 2 if folded.config.use_context else 1
    channels = fc6.in_features // (boxes * size * size)  # of one pooled map (both trunks' without fusion)
    index = torch.arange(fc6.in_features).reshape(-1, channels, size, size).permute(0, 2, 1, 3).reshape(-1)
    with torch.no_grad():
        fc6.weight.copy_(fc6.weight[:, index])
    return folded


class RoiAlignGraph(nn.Module):
    """forward(features (B, C, H, W), rois (R, 5)) -> (R, P, C, P): roi_align as the export writes
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
