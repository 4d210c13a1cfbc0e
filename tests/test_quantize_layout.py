"""a3d.export.quantize.quantize_before_layout: a per-tensor QuantizeLinear moved above the ops
that only move elements gives the same bytes, and stays where moving it would change them."""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from a3d.export.quantize import quantize_before_layout
from tests.helpers.onnx_graphs import run_graph


def _model(scale: np.ndarray, extra_user: bool = False) -> onnx.ModelProto:
    """a (2, 3), b (4, 3) -> Concat -> Reshape (-1) -> QuantizeLinear(scale, 128) -> uint8 out."""
    nodes = [
        helper.make_node("Concat", ["a", "b"], ["joined"], axis=0, name="join"),
        helper.make_node("Reshape", ["joined", "flat_shape"], ["flat"], name="flatten"),
        helper.make_node("QuantizeLinear", ["flat", "scale", "zero"], ["out"], name="quantize", axis=0),
    ]
    outputs = [helper.make_tensor_value_info("out", TensorProto.UINT8, [18])]
    if extra_user:  # the joined floats are needed as floats elsewhere too
        nodes.append(helper.make_node("Identity", ["joined"], ["joined_too"], name="other"))
        outputs.append(helper.make_tensor_value_info("joined_too", TensorProto.FLOAT, [6, 3]))
    initializers = [
        numpy_helper.from_array(np.array([-1], np.int64), "flat_shape"),
        numpy_helper.from_array(scale.astype(np.float32), "scale"),
        numpy_helper.from_array(np.full(scale.shape, 128, np.uint8), "zero"),
    ]
    value = helper.make_tensor_value_info
    inputs = [value(name, TensorProto.FLOAT, [rows, 3]) for name, rows in (("a", 2), ("b", 4))]
    graph = helper.make_graph(nodes, "g", inputs, outputs, initializer=initializers)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def test_quantisation_moves_above_layout_ops_with_the_same_bytes() -> None:
    rng = np.random.default_rng(0)
    feeds = {name: rng.normal(0, 3, (rows, 3)).astype(np.float32) for name, rows in (("a", 2), ("b", 4))}
    before = _model(np.array(0.05))
    want = run_graph(before, feeds)
    after = quantize_before_layout(_model(np.array(0.05)))
    onnx.checker.check_model(after)
    ops = [n.op_type for n in after.graph.node]
    assert ops == ["QuantizeLinear", "QuantizeLinear", "Concat", "Reshape"]  # bytes joined and reshaped
    np.testing.assert_array_equal(run_graph(after, feeds), want)
    assert len(np.unique(want)) > 5  # the inputs span many quantisation steps


def test_per_axis_or_shared_inputs_stay_in_place() -> None:
    per_axis = quantize_before_layout(_model(np.full(18, 0.05)))
    assert [n.op_type for n in per_axis.graph.node][-1] == "QuantizeLinear"
    shared = quantize_before_layout(_model(np.array(0.05), extra_user=True))
    assert [n.op_type for n in shared.graph.node].count("QuantizeLinear") == 1
    assert next(n for n in shared.graph.node if n.op_type == "Concat").input[:] == ["a", "b"]
