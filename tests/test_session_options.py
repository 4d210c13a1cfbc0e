"""The runtime's ONNX Runtime options give an int8 model the same answers on every x86 CPU.

Without an int8 dot product (AVX2 alone, no VNNI) ONNX Runtime's uint8 x int8 kernel adds pairs of
products into 16-bit integers, which saturate; the bundled model lost 17 points of mAP on the
samples that way. ``session_options`` asks for its exact uint8 x uint8 kernel there.
"""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from a3d.runtime.network.model import session_options

WIDTH = 64


def _int8_product() -> bytes:
    """x (1, WIDTH) quantised as uint8 (scale 1) times a constant int8 weight (1 everywhere
    but 127 and -128), QDQ as a3d-export writes it: ONNX Runtime fuses it into an integer product."""
    weight = np.full((WIDTH, 4), 1, np.int8)
    weight[:, 0], weight[:, 1] = 127, -128
    initializers = [
        numpy_helper.from_array(np.array(1.0, np.float32), "one"),
        numpy_helper.from_array(np.array(0, np.uint8), "x_zero"),
        numpy_helper.from_array(np.array(0, np.int8), "w_zero"),
        numpy_helper.from_array(weight, "w"),
    ]
    nodes = [
        helper.make_node("QuantizeLinear", ["x", "one", "x_zero"], ["xq"]),
        helper.make_node("DequantizeLinear", ["xq", "one", "x_zero"], ["xd"]),
        helper.make_node("DequantizeLinear", ["w", "one", "w_zero"], ["wd"]),
        helper.make_node("MatMul", ["xd", "wd"], ["y"]),
    ]
    graph = helper.make_graph(
        nodes, "int8_product", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, WIDTH])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])], initializers,
    )  # fmt: skip
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)]).SerializeToString()


def test_large_int8_products_add_exactly_on_this_cpu() -> None:
    """255 x 127 in every pair: a 16-bit pair sum would saturate at 32767 (this machine's flags)."""
    session = ort.InferenceSession(_int8_product(), session_options(1), providers=["CPUExecutionProvider"])
    y = session.run(None, {"x": np.full((1, WIDTH), 255.0, np.float32)})[0]
    np.testing.assert_array_equal(y, [[WIDTH * 255 * 127, WIDTH * 255 * -128, WIDTH * 255, WIDTH * 255]])


@pytest.mark.parametrize(
    ("flags", "int8", "precise"), [({"avx512_vnni", "avx2"}, "1", ""), ({"avx2"}, "", "1"), (set(), "", "1")]
)
def test_the_exact_kernel_is_asked_for_where_there_is_no_int8_dot_product(flags, int8, precise) -> None:
    options = session_options(1, frozenset(flags))
    assert _entry(options, "session.qdqisint8allowed") == int8
    assert _entry(options, "session.x64quantprecision") == precise


def _entry(options: ort.SessionOptions, key: str) -> str:
    """The option's value, "" where it is not set (ONNX Runtime raises then)."""
    try:
        return options.get_session_config_entry(key)
    except RuntimeError:
        return ""
