"""Static int8 quantisation of the exported graph (``a3d-export --int8 --calib FOLDER``).

ONNX Runtime's ``quantize_static`` in QDQ format, per-channel int8 weights and uint8 activations
(the U8S8 path of x86 VNNI, docs/platform.md "Compute ceilings"), MinMax ranges calibrated on real
frames through the runtime's own front end (a3d.export.verify.folder_inputs), at most
``CALIB_ROIS`` RoIs per frame (the best-ranked proposals) to bound the calibration run's memory.
Quantised: the convolutions and the fully connected layers (Gemm, and MatMul with a constant
weight, which the SVD factors become), and the ReLUs after them: ORT's quantizer then drops each
ReLU and quantises the product's output with the ReLU's range (zero point 0, so the int8 clamp is
the ReLU). Without that, every layer's output went int8 -> float -> ReLU -> int8 between two
int8 convolutions: 57 of 409 ms of the paper's trunks (docs/edge-speed.md). The RoI pooling
products (MatMul of two computed tensors: the bilinear weights and the feature maps) are left out
of ``quantize_static``; fc6's input quantisation is then moved up through the concatenations and
reshapes that join the pooling's chunks (``quantize_before_layout``): each chunk's product is
quantised where it is made, while it is in cache, and 100 MB of float copies become 25 MB of
bytes. Then each chunk's first product, whose other operand is the quantised map, gets its
bilinear weights as bytes too (``quantize_pool_weights``): an integer product on the map's bytes.
Last, those maps are read through an exact int8 copy (``signed_pool_maps``), which lets ONNX
Runtime use its uint8 x int8 kernel where the runtime's session allows int8 activations.

``quant_pre_process`` runs first (graph optimisation, ONNX shape inference) with ORT's symbolic
shape inference skipped: it does not complete on the dynamo exporter's graphs. The float model
must hold its weights inline (external_data=False at export). ORT 1.31's
``CalibMaxIntermediateOutputs`` option drops the collected ranges instead of merging them, so it
is not used (MinMax keeps two numbers per tensor and frame anyway).
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import onnx
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process

from a3d.export.base import ExportError
from a3d.export.verify import NetworkInputs

CALIB_ROIS = 300  # RoIs per calibration frame (the best-ranked proposals)
QUANTIZED_OPS = ("Conv", "Gemm", "MatMul", "Relu")
# Ops that only move or regroup elements: an elementwise QuantizeLinear gives the same bytes
# before them as after. Their data inputs: all of Concat's, the first of the others.
LAYOUT_OPS = {"Concat": None, "Reshape": 1, "Flatten": 1, "Slice": 1, "Squeeze": 1, "Unsqueeze": 1,
              "Transpose": 1}  # fmt: skip
MOVES = tuple(op for op in LAYOUT_OPS if op != "Concat")  # the layout ops of one data input


class _FeedReader(CalibrationDataReader):
    """Feeds one frame's inputs per call (the graph's input names, batch of one, RoIs capped)."""

    def __init__(self, inputs: list[NetworkInputs], rois: int) -> None:
        self._items = iter(inputs)
        self._rois = rois

    def get_next(self) -> dict[str, np.ndarray] | None:
        item = next(self._items, None)
        if item is None:
            return None
        return {
            "color": np.ascontiguousarray(item.color, np.float32),
            "depth": np.ascontiguousarray(item.depth, np.float32),
            "rois": np.ascontiguousarray(item.rois[: self._rois], np.float32),
            "context_rois": np.ascontiguousarray(item.context_rois[: self._rois], np.float32),
        }


def computed_matmuls(model: onnx.ModelProto) -> list[str]:
    """Names of the MatMul nodes none of whose inputs is a weight (initializer or Constant)."""
    graph = model.graph
    constants = {i.name for i in graph.initializer}
    constants |= {out for n in graph.node if n.op_type == "Constant" for out in n.output}
    nodes = [n for n in graph.node if n.op_type == "MatMul" and not constants.intersection(n.input)]
    if any(not n.name for n in nodes):
        raise ExportError("an unnamed MatMul node in the graph cannot be kept out of quantisation")
    return [n.name for n in nodes]


def quantize_int8(
    float_model: str | os.PathLike,
    out: str | os.PathLike,
    calibration: Iterable[NetworkInputs],
    rois_per_frame: int = CALIB_ROIS,
) -> int:
    """Write the int8 QDQ model of ``float_model`` to ``out``; returns the number of frames used."""
    inputs = list(calibration)
    if not inputs:
        raise ExportError("--calib: no calibration frame with a usable proposal")
    out = Path(out)
    prepared = out.with_name(out.stem + ".pre.onnx")
    quant_pre_process(str(float_model), str(prepared), skip_symbolic_shape=True)
    try:
        quantize_static(
            str(prepared),
            str(out),
            _FeedReader(inputs, rois_per_frame),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            op_types_to_quantize=list(QUANTIZED_OPS),
            nodes_to_exclude=computed_matmuls(onnx.load(str(prepared))),
        )
    finally:
        prepared.unlink(missing_ok=True)
    model = signed_pool_maps(quantize_pool_weights(quantize_before_layout(onnx.load(str(out)))))
    used = {"", *(n.domain for n in model.graph.node)}
    kept = [o for o in model.opset_import if o.domain in used]  # the pre-processing declares ORT's domains
    del model.opset_import[:]
    model.opset_import.extend(kept)
    onnx.save(model, str(out))
    return len(inputs)


def producer_through(producers: dict[str, onnx.NodeProto], name: str, skipped: tuple[str, ...]):
    """The node that makes ``name`` (``producers``: output name -> node), looking through the ops
    in ``skipped`` (their first input); None for a graph input or initializer."""
    node = producers.get(name)
    while node is not None and node.op_type in skipped:
        node = producers.get(node.input[0])
    return node


def _map_products(model: onnx.ModelProto) -> list[tuple[onnx.NodeProto, onnx.NodeProto]]:
    """The RoI pooling products on a dequantised map (the first of each chunk's two window
    products): (the computed MatMul, the map's DequantizeLinear that its second input comes from
    through single-input layout ops)."""
    producers = {out: n for n in model.graph.node for out in n.output}
    computed = set(computed_matmuls(model))
    found = []
    for product in model.graph.node:
        source = producer_through(producers, product.input[1], MOVES) if product.name in computed else None
        if source is not None and source.op_type == "DequantizeLinear":
            found.append((product, source))
    return found


def quantize_pool_weights(model: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` (changed in place) with the bilinear weights of each RoI pooling product on a
    dequantised map (``_map_products``) quantised to uint8 with the fixed scale 1/255 (the weights
    lie in [0, 1]) once, where they are made, and dequantised where each product reads them: the
    chunks' slices of the weights move bytes, and ONNX Runtime runs each product as
    MatMulIntegerToFloat on the window's bytes, with no dequantised copy of the window
    (docs/edge-speed.md "Integer row products, a costed order")."""
    graph = model.graph
    scale, zero = "pool_weights_scale", "pool_weights_zero_point"
    producers = {out: n for n in graph.node for out in n.output}
    readers = Counter(name for n in graph.node for name in n.input)
    quantized: dict[str, str] = {}  # weights -> their bytes
    retyped: set[str] = set()
    products = [product for product, _ in _map_products(model)]
    for product in products:
        # the layout ops that this product's weights alone pass through, and the tensor before them
        first, weights = product, product.input[0]
        while (
            (node := producers.get(weights)) is not None and node.op_type in MOVES and readers[weights] == 1
        ):
            first, weights = node, node.input[0]
            retyped.add(node.output[0])
        if weights not in quantized:
            quantized[weights] = f"{weights}/pool_weights_quantized"
            maker = producers.get(weights)
            at = list(graph.node).index(maker) + 1 if maker is not None else 0
            graph.node.insert(at, onnx.helper.make_node(
                "QuantizeLinear", [weights, scale, zero], [quantized[weights]],
                name=f"{weights}/pool_weights_quantize"))  # fmt: skip
        read = quantized[weights] if first is product else product.input[0]
        if first is not product:
            first.input[0] = quantized[weights]
        graph.node.insert(list(graph.node).index(product), onnx.helper.make_node(
            "DequantizeLinear", [read, scale, zero], [f"{product.name}/weights_dequantized"],
            name=f"{product.name}/weights_dequantize"))  # fmt: skip
        product.input[0] = f"{product.name}/weights_dequantized"
    if products:
        graph.initializer.extend([onnx.numpy_helper.from_array(np.array(1 / 255, np.float32), scale),
                                  onnx.numpy_helper.from_array(np.array(0, np.uint8), zero)])  # fmt: skip
    kept = [v for v in graph.value_info if v.name not in retyped]
    del graph.value_info[:]
    graph.value_info.extend(kept)
    return model


def signed_pool_maps(model: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` (changed in place) with each uint8 map that the RoI pooling's integer products
    read (``_map_products``) quantised again as int8 right after its dequantisation: the same
    scale and the zero point less 128, so the same values exactly. Where a3d's session allows int8
    activations (``a3d.runtime.network.model.session_options``: CPUs whose int8 dot product adds
    uint8 x int8 exactly) ONNX Runtime runs the products on that kernel, the windows as the int8
    operand (docs/edge-speed.md "Signed windows, an order for the intermediate"); elsewhere it
    turns the windows back to uint8."""
    graph = model.graph
    initializers = {i.name: i for i in graph.initializer}
    maps = {dequantize.output[0]: dequantize for _, dequantize in _map_products(model)}
    for cells, dequantize in maps.items():
        scale, zero = [*dequantize.input[1:], ""][:2]
        if scale not in initializers or (zero and zero not in initializers):
            continue
        zero_point = onnx.numpy_helper.to_array(initializers[zero]) if zero else np.array(0, np.uint8)
        if zero_point.dtype != np.uint8 or zero_point.ndim or initializers[scale].dims:
            continue  # per-tensor uint8 maps only
        signed_zero = f"{cells}/int8_zero_point"
        graph.initializer.append(
            onnx.numpy_helper.from_array(np.array(int(zero_point) - 128, np.int8), signed_zero)
        )
        for node in graph.node:
            node.input[:] = [f"{cells}/int8_dequantized" if name == cells else name for name in node.input]
        at = list(graph.node).index(dequantize) + 1
        graph.node.insert(at, onnx.helper.make_node(
            "DequantizeLinear", [f"{cells}/int8", scale, signed_zero], [f"{cells}/int8_dequantized"],
            name=f"{cells}/int8_dequantize"))  # fmt: skip
        graph.node.insert(at, onnx.helper.make_node(
            "QuantizeLinear", [cells, scale, signed_zero], [f"{cells}/int8"],
            name=f"{cells}/int8_quantize"))  # fmt: skip
    return model


def quantize_before_layout(model: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` (changed in place) with every per-tensor QuantizeLinear whose input a layout op
    (``LAYOUT_OPS``) makes for it alone moved to that op's data inputs, repeatedly: the layout ops
    then move uint8 instead of float32. Per-tensor only (a scalar scale): a per-axis scale follows
    an axis that a reshape would move."""
    graph = model.graph
    scalars = {i.name for i in graph.initializer if not i.dims}
    outputs = {o.name for o in graph.output}
    retyped: set[str] = set()
    pending = [n for n in graph.node if n.op_type == "QuantizeLinear" and set(n.input[1:]) <= scalars]
    while pending:
        quantize = pending.pop()
        source = quantize.input[0]
        layout = next((n for n in graph.node if source in n.output), None)
        users = sum(name == source for n in graph.node for name in n.input)
        if layout is None or layout.op_type not in LAYOUT_OPS or users != 1 or source in outputs:
            continue
        data = len(layout.input) if LAYOUT_OPS[layout.op_type] is None else LAYOUT_OPS[layout.op_type]
        at = list(graph.node).index(layout)
        for i in range(data):
            name = f"{quantize.name}/{layout.name}/{i}"
            moved = onnx.helper.make_node(
                "QuantizeLinear", [layout.input[i], *quantize.input[1:]], [name + "_quantized"], name=name
            )
            graph.node.insert(at, moved)
            layout.input[i] = moved.output[0]
            pending.append(moved)
        retyped.add(source)
        layout.output[0] = quantize.output[0]
        graph.node.remove(quantize)
    kept = [v for v in graph.value_info if v.name not in retyped]
    del graph.value_info[:]
    graph.value_info.extend(kept)
    return model
