"""a3d.export.refold: an older export's pooled-map Transposes folded into fc6's weight columns,
with the same answers; a model without them (the bundled one, refolded) is refused in one line."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from a3d.export.base import ExportError
from a3d.export.refold import main, refold_graph
from a3d.runtime.models import model_path
from tests.helpers.onnx_graphs import run_graph

P, C, N = 3, 4, 5  # pool size, channels, fc6 outputs


def _old_head(rng: np.random.Generator) -> onnx.ModelProto:
    """Two pooled maps a, b (R, P * C * P) in (y, c, x) order -> (R, P, C, P) -> Transpose to
    (c, y, x) -> flatten -> join -> QuantizeLinear / DequantizeLinear -> Gemm with per-row int8
    weights (transB): the shape of a head exported before fold_pool_layout."""
    nodes, initializers = [], []
    for name in ("a", "b"):
        nodes += [
            helper.make_node("Reshape", [name, "pooled_shape"], [f"{name}_pooled"]),
            helper.make_node("Transpose", [f"{name}_pooled"], [f"{name}_cyx"], perm=[0, 2, 1, 3]),
            helper.make_node("Reshape", [f"{name}_cyx", "flat_shape"], [f"{name}_flat"]),
        ]
    nodes += [
        helper.make_node("Concat", ["a_flat", "b_flat"], ["joined"], axis=1),
        helper.make_node("QuantizeLinear", ["joined", "scale", "zero"], ["joined_q"]),
        helper.make_node("DequantizeLinear", ["joined_q", "scale", "zero"], ["joined_dq"]),
        helper.make_node("DequantizeLinear", ["w_q", "w_scale", "w_zero"], ["w"], axis=0),
        helper.make_node("Gemm", ["joined_dq", "w", "bias"], ["out"], transB=1),
    ]
    weights = rng.integers(-127, 128, (N, 2 * C * P * P)).astype(np.int8)
    for value, name in (
        (np.array([-1, P, C, P], np.int64), "pooled_shape"),
        (np.array([-1, C * P * P], np.int64), "flat_shape"),
        (np.float32(0.05), "scale"), (np.uint8(128), "zero"), (weights, "w_q"),
        (rng.uniform(0.01, 0.02, N).astype(np.float32), "w_scale"), (np.zeros(N, np.int8), "w_zero"),
        (rng.normal(0, 1, N).astype(np.float32), "bias"),
    ):  # fmt: skip
        initializers.append(numpy_helper.from_array(np.asarray(value), name))
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, ["R", P * C * P]) for n in ("a", "b")]
    output = [helper.make_tensor_value_info("out", TensorProto.FLOAT, ["R", N])]
    graph = helper.make_graph(nodes, "head", inputs, output, initializer=initializers)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def test_refold_drops_the_transposes_with_the_same_answers() -> None:
    rng = np.random.default_rng(1)
    feeds = {n: rng.normal(0, 3, (6, P * C * P)).astype(np.float32) for n in ("a", "b")}
    old = _old_head(np.random.default_rng(0))
    want = run_graph(old, feeds)
    new = refold_graph(_old_head(np.random.default_rng(0)))
    ops = [n.op_type for n in new.graph.node]
    assert "Transpose" not in ops
    quantized = sorted(n.input[0] for n in new.graph.node if n.op_type == "QuantizeLinear")
    assert quantized == ["a", "b"]  # moved above the reshapes and the join: they move bytes
    np.testing.assert_allclose(run_graph(new, feeds), want, rtol=1e-5, atol=1e-5)  # the same sums, reordered
    assert np.abs(want).max() > 1.0  # the answers are not trivially zero
    with pytest.raises(ExportError, match="already folded"):
        refold_graph(new)


def test_the_bundled_model_is_refolded_and_a_second_refold_is_one_line(tmp_path, capsys) -> None:
    out = tmp_path / "again.onnx"
    assert main([str(model_path("live")), "-o", str(out)]) == 2
    assert "no pooled-map Transpose before fc6" in capsys.readouterr().err
    assert not out.exists()
    assert main([str(tmp_path / "absent.onnx"), "-o", str(out)]) == 2
    assert "absent.onnx: no such model file" in capsys.readouterr().err
