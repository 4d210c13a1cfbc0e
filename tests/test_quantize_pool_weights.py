"""a3d.export.quantize.quantize_pool_weights: the bilinear weights of a pooling product on a
dequantised map are quantised (uint8, 1/255) where the product reads them, so that ONNX Runtime
runs it as an integer product; a product on float data stays as it is. signed_pool_maps: that map
is read through an exact int8 copy, which ONNX Runtime keeps int8 where a3d's session options
allow it (CPUs with an int8 dot product)."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from a3d.export.quantize import quantize_pool_weights, signed_pool_maps
from a3d.runtime.network.cpu_support import int8_dot_products
from a3d.runtime.network.model import session_options
from tests.helpers.onnx_graphs import run_graph

MAP_SCALE, MAP_ZERO = 0.05, 7
# per chunk: its rows of wy and of the map (initializer names: zero, one, two, four, five)
CHUNKS = (("a", ("zero", "one"), ("one", "five")), ("b", ("one", "two"), ("zero", "four")))


def _model() -> onnx.ModelProto:
    """map (6, 20) uint8 -> DequantizeLinear: cells. Two chunks' row products, "rows" and
    "rows_b": each a slice of wy (2, 7, 4), flattened to (7, 4), x its window (cells' rows 1..4,
    0..3); joined, and "columns" = wx (3, 14) x that: the row products read a dequantised map,
    the column one not."""
    make = helper.make_node
    nodes = [
        make("DequantizeLinear", ["map", "map_scale", "map_zero"], ["cells"], name="dequantize"),
        *(
            node
            for chunk, (start, end), (low, high) in CHUNKS
            for node in (
                make("Slice", ["cells", low, high, "zero"], [f"window_{chunk}"], name=f"window_{chunk}"),
                make("Slice", ["wy", start, end, "zero"], [f"wy_{chunk}"], name=f"slice_{chunk}"),
                make("Flatten", [f"wy_{chunk}"], [f"flat_{chunk}"], axis=2, name=f"flatten_{chunk}"),
            )
        ),
        make("MatMul", ["flat_a", "window_a"], ["rows_a"], name="rows"),
        make("MatMul", ["flat_b", "window_b"], ["rows_b"], name="rows_b"),
        make("Concat", ["rows_a", "rows_b"], ["by_rows"], axis=0, name="join"),
        make("MatMul", ["wx", "by_rows"], ["out"], name="columns"),
    ]
    initializers = [
        numpy_helper.from_array(np.array(MAP_SCALE, np.float32), "map_scale"),
        numpy_helper.from_array(np.array(MAP_ZERO, np.uint8), "map_zero"),
        *(
            numpy_helper.from_array(np.array([v], np.int64), n)
            for n, v in (("zero", 0), ("one", 1), ("two", 2), ("four", 4), ("five", 5))
        ),
    ]
    value = helper.make_tensor_value_info
    inputs = [value("map", TensorProto.UINT8, [6, 20]), value("wy", TensorProto.FLOAT, [2, 7, 4]),
              value("wx", TensorProto.FLOAT, [3, 14])]  # fmt: skip
    graph = helper.make_graph(
        nodes, "g", inputs, [value("out", TensorProto.FLOAT, [3, 20])], initializer=initializers
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def _feeds() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {"map": rng.integers(0, 256, (6, 20)).astype(np.uint8),
            "wy": rng.uniform(0.0, 1.0, (2, 7, 4)).astype(np.float32),
            "wx": rng.uniform(0.0, 1.0, (3, 14)).astype(np.float32)}  # fmt: skip


def test_the_row_products_read_their_weights_as_bytes_quantised_once() -> None:
    model = quantize_pool_weights(_model())
    onnx.checker.check_model(model)
    nodes = {n.name: n for n in model.graph.node}
    makers = {out: n for n in model.graph.node for out in n.output}
    (quantize,) = [n for n in model.graph.node if n.op_type == "QuantizeLinear"]
    assert quantize.input[0] == "wy"  # once, where the weights are made: the chunks slice bytes
    assert {nodes[f"slice_{c}"].input[0] for c in "ab"} == {quantize.output[0]}
    assert all(makers[nodes[p].input[0]].op_type == "DequantizeLinear" for p in ("rows", "rows_b"))
    assert nodes["columns"].input[0] == "wx"  # the column product reads float rows: untouched
    scales = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    assert scales[quantize.input[1]] == np.float32(1 / 255) and scales[quantize.input[2]].dtype == np.uint8
    feeds = _feeds()
    cells = (feeds["map"].astype(np.float64) - MAP_ZERO) * MAP_SCALE
    wy = feeds["wy"].astype(np.float64)

    def pooled(weights: np.ndarray) -> np.ndarray:  # the two chunks' products on their windows, joined
        return feeds["wx"] @ np.vstack([weights[0] @ cells[1:5], weights[1] @ cells[0:4]])

    np.testing.assert_allclose(
        run_graph(model, feeds), pooled(np.round(wy * 255) / 255), rtol=1e-5, atol=1e-5
    )
    assert np.abs(run_graph(_model(), feeds) - pooled(wy)).max() < 1e-4  # rounding: well above that
    assert np.abs(pooled(np.round(wy * 255) / 255) - pooled(wy)).max() > 1e-3


def test_onnx_runtime_runs_them_as_integer_products(tmp_path) -> None:
    options = ort.SessionOptions()
    options.optimized_model_filepath = str(tmp_path / "optimized.onnx")
    ort.InferenceSession(quantize_pool_weights(_model()).SerializeToString(), options,
                         providers=["CPUExecutionProvider"])  # fmt: skip
    ops = [n.op_type for n in onnx.load(str(tmp_path / "optimized.onnx")).graph.node]
    assert (
        ops.count("MatMulIntegerToFloat") == 2 and ops.count("MatMul") == 1
    )  # the column product stays float


def test_the_row_product_reads_an_exact_int8_copy_of_the_map() -> None:
    model = signed_pool_maps(quantize_pool_weights(_model()))
    onnx.checker.check_model(model)
    makers = {out: n for n in model.graph.node for out in n.output}
    constants = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    dequantize = makers[makers["window_a"].input[0]]  # the windows' slices read the copy
    assert makers["window_b"].input[0] == dequantize.output[0]
    quantize = makers[dequantize.input[0]]
    assert (dequantize.op_type, quantize.op_type, quantize.input[0]) == (
        "DequantizeLinear",
        "QuantizeLinear",
        "cells",
    )
    zero = constants[quantize.input[2]]
    assert zero.dtype == np.int8 and int(zero) == MAP_ZERO - 128 and quantize.input[1] == "map_scale"
    feeds = _feeds()
    np.testing.assert_array_equal(run_graph(model, feeds), run_graph(quantize_pool_weights(_model()), feeds))


@pytest.mark.parametrize(("flags", "window_type"), [({"avx512_vnni", "avx2"}, np.int8), ({"avx2"}, np.uint8)])
def test_onnx_runtime_multiplies_int8_windows_where_the_cpu_adds_them_exactly(
    tmp_path, flags, window_type
) -> None:
    options = session_options(1, frozenset(flags))
    options.optimized_model_filepath = str(tmp_path / "optimized.onnx")
    model = signed_pool_maps(quantize_pool_weights(_model()))
    session = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    optimized = onnx.load(str(tmp_path / "optimized.onnx")).graph
    constants = {t.name: numpy_helper.to_array(t) for t in optimized.initializer}
    products = [n for n in optimized.node if n.op_type == "MatMulIntegerToFloat"]
    assert len(products) == 2  # the window's zero point: its type
    assert all(constants[product.input[5]].dtype == window_type for product in products)
    if int8_dot_products(frozenset(flags)) and not int8_dot_products():
        return  # a dot product this CPU lacks: its int8 kernel would saturate (test_session_options)
    feeds = _feeds()  # the same answers either way: both kernels add exactly
    np.testing.assert_array_equal(
        session.run(None, feeds)[0], run_graph(quantize_pool_weights(_model()), feeds)
    )


def test_a_graph_without_such_a_product_is_unchanged() -> None:
    model = _model()
    for product in (n for n in model.graph.node if n.name in ("rows", "rows_b")):
        product.input[1] = "window_again"  # the row products now read a graph input, not the map
    model.graph.input.append(helper.make_tensor_value_info("window_again", TensorProto.FLOAT, [4, 20]))
    before = model.SerializeToString()
    assert signed_pool_maps(quantize_pool_weights(model)).SerializeToString() == before
