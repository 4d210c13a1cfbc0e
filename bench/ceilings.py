"""The machine's own compute ceilings, measured through ONNX Runtime in the benchmark's run.

A time in seconds says little across machines whose instruction sets differ from day to day
(AVX2 only, AVX-512, VNNI, AMX): the same int8 model is ~2x faster than fp32 on one and ~4x
on another. So the edge benchmark measures, in the same run and with the same thread count,
what ONNX Runtime reaches on large shapes of the two kinds of work the network does, in both
precisions, and judges each part of the network against the matching ceiling:

- GEMM (the head: fc6 / fc7 over all RoIs): MatMul fp32 and QLinearMatMul uint8 x int8, 512 x
  4096 x 4096 (about 500 RoIs through an fc layer of 4096);
- convolution (the trunks: VGG16's 3 x 3 layers): Conv fp32 and QLinearConv uint8 x int8 with
  per-channel weights (what ONNX Runtime fuses the exported QDQ convolutions into), 256 -> 256
  channels on a 112 x 140 map (conv3 of a 427 x 561 frame), 8.3 GMAC.

The graphs are built with onnx.helper, random weights; each ceiling is the median of a few
calls after a warm-up, in MAC/s (one multiply-add = one MAC).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from a3d.runtime.network.model import session_options

GEMM = (512, 4096, 4096)  # M (RoIs), K, N
CONV = (256, 256, 112, 140)  # in channels, out channels, height, width; 3 x 3, padding 1
OPSET = 17


@dataclass(frozen=True)
class Ceilings:
    """MAC/s ONNX Runtime reached on this machine: GEMM and convolution, fp32 and int8."""

    gemm_fp32: float
    gemm_int8: float
    conv_fp32: float
    conv_int8: float
    threads: int

    def conv(self, int8: bool) -> float:
        return self.conv_int8 if int8 else self.conv_fp32

    def gemm(self, int8: bool) -> float:
        return self.gemm_int8 if int8 else self.gemm_fp32

    def best(self, other: Ceilings) -> Ceilings:
        """Each ceiling's higher measurement: the machine's limit is what it reached when least disturbed."""
        rates = {
            f: max(getattr(self, f), getattr(other, f))
            for f in ("gemm_fp32", "gemm_int8", "conv_fp32", "conv_int8")
        }
        return Ceilings(threads=self.threads, **rates)


def gemm_graph(m: int, k: int, n: int, int8: bool) -> tuple[onnx.ModelProto, dict[str, np.ndarray]]:
    """(model, feeds) of one (m, k) x (k, n) product with a constant weight."""
    rng = np.random.default_rng(0)
    if not int8:
        weight = numpy_helper.from_array(rng.standard_normal((k, n), np.float32), "w")
        node = helper.make_node("MatMul", ["x", "w"], ["y"])
        feeds = {"x": rng.standard_normal((m, k), np.float32)}
        return _model(node, [weight], "x", TensorProto.FLOAT, (m, k), "y", TensorProto.FLOAT, (m, n)), feeds
    constants = [
        numpy_helper.from_array(rng.integers(-127, 128, (k, n), dtype=np.int8), "w"),
        *_scalars(x_scale=0.02, w_scale=0.01, y_scale=0.5),
        numpy_helper.from_array(np.array(128, np.uint8), "x_zero"),
        numpy_helper.from_array(np.array(0, np.int8), "w_zero"),
        numpy_helper.from_array(np.array(128, np.uint8), "y_zero"),
    ]
    node = helper.make_node(
        "QLinearMatMul", ["x", "x_scale", "x_zero", "w", "w_scale", "w_zero", "y_scale", "y_zero"], ["y"]
    )
    feeds = {"x": rng.integers(0, 256, (m, k), dtype=np.uint8)}
    return _model(node, constants, "x", TensorProto.UINT8, (m, k), "y", TensorProto.UINT8, (m, n)), feeds


def conv_graph(
    c_in: int, c_out: int, height: int, width: int, int8: bool
) -> tuple[onnx.ModelProto, dict[str, np.ndarray]]:
    """(model, feeds) of one 3 x 3 convolution, padding 1, with bias."""
    rng = np.random.default_rng(0)
    shape, out, pads = (1, c_in, height, width), (1, c_out, height, width), [1, 1, 1, 1]
    if not int8:
        constants = [
            numpy_helper.from_array(rng.standard_normal((c_out, c_in, 3, 3), np.float32), "w"),
            numpy_helper.from_array(rng.standard_normal(c_out).astype(np.float32), "b"),
        ]
        node = helper.make_node("Conv", ["x", "w", "b"], ["y"], pads=pads)
        feeds = {"x": rng.standard_normal(shape, np.float32)}
        return _model(node, constants, "x", TensorProto.FLOAT, shape, "y", TensorProto.FLOAT, out), feeds
    constants = [
        numpy_helper.from_array(rng.integers(-127, 128, (c_out, c_in, 3, 3), dtype=np.int8), "w"),
        numpy_helper.from_array(np.full(c_out, 0.01, np.float32), "w_scale"),  # per channel
        numpy_helper.from_array(np.zeros(c_out, np.int8), "w_zero"),
        numpy_helper.from_array(rng.integers(-1000, 1000, c_out, dtype=np.int32), "b"),
        *_scalars(x_scale=0.02, y_scale=0.5),
        numpy_helper.from_array(np.array(128, np.uint8), "x_zero"),
        numpy_helper.from_array(np.array(128, np.uint8), "y_zero"),
    ]
    inputs = ["x", "x_scale", "x_zero", "w", "w_scale", "w_zero", "y_scale", "y_zero", "b"]
    node = helper.make_node("QLinearConv", inputs, ["y"], pads=pads)
    feeds = {"x": rng.integers(0, 256, shape, dtype=np.uint8)}
    return _model(node, constants, "x", TensorProto.UINT8, shape, "y", TensorProto.UINT8, out), feeds


def _scalars(**values: float) -> list[onnx.TensorProto]:
    return [numpy_helper.from_array(np.array(v, np.float32), name) for name, v in values.items()]


def _model(node, constants, x: str, x_type: int, shape, y: str, y_type: int, out_shape) -> onnx.ModelProto:
    graph = helper.make_graph(
        [node],
        node.op_type,
        [helper.make_tensor_value_info(x, x_type, list(shape))],
        [helper.make_tensor_value_info(y, y_type, out_shape)],
        initializer=constants,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    onnx.checker.check_model(model)
    return model


def macs_per_second(model: onnx.ModelProto, feeds: dict[str, np.ndarray], macs: int, threads: int,
                    repeats: int = 5) -> float:  # fmt: skip
    """The median MAC/s of ``repeats`` calls after one warm-up, with the runtime's session settings
    (a3d.runtime.network.model.session_options: ``threads`` intra-op threads, one inter-op, and on
    a CPU with AVX2 alone ONNX Runtime's exact int8 kernel, the one the runtime's model runs on)."""
    options = session_options(threads)
    session = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    session.run(None, feeds)
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        session.run(None, feeds)
        seconds.append(time.perf_counter() - start)
    return macs / float(np.median(seconds))


def measure_ceilings(threads: int, scale: float = 1.0, repeats: int = 5) -> Ceilings:
    """The four ceilings; ``scale`` < 1 shrinks the shapes (tests) keeping their kind."""
    m, k, n = (max(8, round(d * scale)) for d in GEMM)
    c_in, c_out, h, w = (max(8, round(d * scale)) for d in CONV)
    gemm_macs, conv_macs = m * k * n, c_in * c_out * 9 * h * w
    rates = {}
    for int8 in (False, True):
        name = "int8" if int8 else "fp32"
        rates[f"gemm_{name}"] = macs_per_second(*gemm_graph(m, k, n, int8), gemm_macs, threads, repeats)
        rates[f"conv_{name}"] = macs_per_second(
            *conv_graph(c_in, c_out, h, w, int8), conv_macs, threads, repeats
        )
    return Ceilings(threads=threads, **rates)
