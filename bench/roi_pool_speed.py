"""RoI pooling alone in ONNX Runtime: the exported dense form against ONNX's RoiAlign operator.

    .venv/bin/python -m bench.roi_pool_speed [--rois 500] [--channels 512] [--map 27x36] [--threads 2]

The exported graph pools each map (RoI and context) as two products (train/model/roi_pool.py):
the bilinear row weights (R x 7, H) times the map (H, C x W), then the column weights per RoI,
and a transpose to (R, C, 7, 7); the first product writes an R x 7 x C x W fp32 intermediate
(258 MB at the paper's sizes, the defaults). ONNX's RoiAlign (avg, sampling ratio 2, half-pixel)
computes the same pooling by sampling. Both are timed here on random maps and RoIs inside the
map, interleaved, median of ``--repeats`` calls, to see whether swapping the form would help the
head (docs/edge-speed.md).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import onnxruntime as ort
from onnx import TensorProto, helper

POOL, SAMPLING, STRIDE = 7, 2, 16


def _session(graph, threads: int) -> ort.InferenceSession:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])


def _value(name: str, dtype: int, shape) -> object:
    return helper.make_tensor_value_info(name, dtype, shape)


def dense_graph(rois: int, channels: int, height: int, width: int):
    """The exported form: map (1, C, H, W), row weights (R*7, H), column weights (R, W, 7) -> (R, C, 7, 7)."""
    shapes = {"hcw": [height, channels * width], "rows": [rois, POOL * channels, width],
              "out": [rois, POOL, channels, POOL]}  # fmt: skip
    nodes = [
        helper.make_node("Transpose", ["map"], ["map_h"], perm=[0, 2, 1, 3]),
        helper.make_node("Reshape", ["map_h", "hcw"], ["map_2d"]),
        helper.make_node("MatMul", ["row_weights", "map_2d"], ["by_rows"]),
        helper.make_node("Reshape", ["by_rows", "rows"], ["by_rows_3d"]),
        helper.make_node("MatMul", ["by_rows_3d", "column_weights"], ["pooled"]),
        helper.make_node("Reshape", ["pooled", "out"], ["pooled_4d"]),
        helper.make_node("Transpose", ["pooled_4d"], ["y"], perm=[0, 2, 1, 3]),
    ]
    inputs = [_value("map", TensorProto.FLOAT, [1, channels, height, width]),
              _value("row_weights", TensorProto.FLOAT, [rois * POOL, height]),
              _value("column_weights", TensorProto.FLOAT, [rois, width, POOL])]  # fmt: skip
    constants = [helper.make_tensor(k, TensorProto.INT64, [len(v)], v) for k, v in shapes.items()]
    output = [_value("y", TensorProto.FLOAT, [rois, channels, POOL, POOL])]
    return helper.make_graph(nodes, "dense", inputs, output, initializer=constants)


def roi_align_graph(rois: int, channels: int, height: int, width: int):
    node = helper.make_node("RoiAlign", ["map", "rois", "batch"], ["y"], mode="avg", output_height=POOL,
                            output_width=POOL, sampling_ratio=SAMPLING, spatial_scale=1 / STRIDE,
                            coordinate_transformation_mode="half_pixel")  # fmt: skip
    inputs = [_value("map", TensorProto.FLOAT, [1, channels, height, width]),
              _value("rois", TensorProto.FLOAT, [rois, 4]),
              _value("batch", TensorProto.INT64, [rois])]  # fmt: skip
    return helper.make_graph(
        [node], "roi_align", inputs, [_value("y", TensorProto.FLOAT, [rois, channels, 7, 7])]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.roi_pool_speed", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--rois", type=int, default=500)
    parser.add_argument("--channels", type=int, default=512, help="fused channels (vgg16-fused: 512)")
    parser.add_argument("--map", default="27x36", help="feature map H x W (427 x 561 / 16: 27 x 36)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    height, width = (int(v) for v in args.map.split("x"))
    rng = np.random.default_rng(0)
    feature_map = rng.standard_normal((1, args.channels, height, width), np.float32)
    corner = rng.uniform(0, [STRIDE * width - 64, STRIDE * height - 64], (args.rois, 2))
    size = rng.uniform(16, [STRIDE * width / 2, STRIDE * height / 2], (args.rois, 2))
    boxes = np.hstack([corner, corner + size]).astype(np.float32)
    forms = {
        "dense products (exported)": (
            _session(dense_graph(args.rois, args.channels, height, width), args.threads),
            {"map": feature_map, "row_weights": rng.random((args.rois * POOL, height), np.float32),
             "column_weights": rng.random((args.rois, width, POOL), np.float32)},
        ),
        "ONNX RoiAlign": (
            _session(roi_align_graph(args.rois, args.channels, height, width), args.threads),
            {"map": feature_map, "rois": boxes, "batch": np.zeros(args.rois, np.int64)},
        ),
    }  # fmt: skip
    seconds: dict[str, list[float]] = {name: [] for name in forms}
    for repeat in range(args.repeats + 1):  # the first round warms up
        for name, (session, feeds) in forms.items():
            start = time.perf_counter()
            session.run(None, feeds)
            if repeat:
                seconds[name].append(time.perf_counter() - start)
    one, five, fifteen = os.getloadavg()
    print(f"RoI pooling of one map, {args.rois} RoIs x {args.channels} channels on {height} x {width}, "
          f"{args.threads} threads (load average {one:.2f} {five:.2f} {fifteen:.2f}); "
          "median ms:")  # fmt: skip
    for name, values in seconds.items():
        print(f"  {name:28s}{1e3 * float(np.median(values)):9.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
