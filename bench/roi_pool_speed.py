"""RoI pooling alone in ONNX Runtime: the exported dense form against other exact formulations.

    .venv/bin/python -m bench.roi_pool_speed [--rois 500] [--channels 512] [--map 27x36] [--threads 2]
        [--chunks 8] [--repeats 7]

The exported graph pools each map (RoI and context) as two products (train/model/roi_pool.py):
the bilinear row weights (R x 7, H) times the map (H, C x W), then the column weights per RoI,
and a transpose to (R, C, 7, 7); the first product writes an R x 7 x C x W fp32 intermediate
(258 MB at the paper's sizes, the defaults). Each form below computes the same pooling from the
same weights (``a3d.train.model.roi_pool``'s, so the row and column weights are the real sparse
ones) and is checked against torch's ``roi_align`` before it is timed:

- ``dense`` the form exported until now; ``dense, no transpose`` the same without the last transpose (what
  folding it into fc6's weight order at export would give); ``dense, N chunks`` the RoIs in N
  slices so each slice's intermediate is smaller;
- ``RoiAlign`` ONNX's operator (avg, sampling ratio 2, half-pixel);
- ``crops`` the RoIs sorted by the area of their weights' support, in N chunks; each chunk
  gathers every RoI's own window (the chunk's largest) from a channels-last map and applies the
  two products to it; the chunk of the largest RoIs uses the dense form on the whole map;
- ``windows`` what a3d-export now writes for models of 256 channels or more (a3d.export.roi_pool_onnx,
  exported here through torch.onnx from the same code, the bilinear weights computed in the
  graph as in the model): ``POOL_CHUNKS`` chunks of consecutive RoIs, each on the union of its
  RoIs' supports sliced channels-last from the map, output (R, 7, 7, C) for fc6's weights to absorb.

The RoIs are handed over in a3d-run's order (a3d.runtime.network.roi_order) for every form; the
crops form sorts them again and puts the rows back with a Gather. RoIs: the paper's frame
(427 x 561 pixels on a 27 x 36 map), sizes log-uniform from 16 pixels to the whole frame as
proposals are (most small, a few large). Each form is timed in two blocks of ``--repeats`` calls
after a warm-up call, the blocks interleaved; the median. Last, the window products'
multiply-adds and float intermediate with the RoIs as given, in a3d-run's order, and with every
RoI on its own window.
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from collections.abc import Callable

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import ModelProto, TensorProto, helper, numpy_helper

from a3d.export.roi_pool_onnx import export_roi_align
from a3d.runtime.network.roi_order import POOL_CHUNKS, chunk_bounds, pooling_order
from a3d.train.model.roi_pool import _axis_weights, roi_align

POOL, SAMPLING, STRIDE = 7, 2, 16


class Graph:
    """A small ONNX graph builder: ``g("Op", *inputs, **attrs)`` adds a node and names its output."""

    def __init__(self) -> None:
        self.nodes: list = []
        self.initializers: list = []
        self.count = 0

    def _name(self) -> str:
        self.count += 1
        return f"v{self.count}"

    def const(self, value) -> str:
        name = self._name()
        self.initializers.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def ints(self, *values: int) -> str:
        return self.const(np.array(values, np.int64))

    def __call__(self, op: str, *inputs: str, outputs: int = 1, **attrs):
        names = [self._name() for _ in range(outputs)]
        self.nodes.append(helper.make_node(op, list(inputs), names, **attrs))
        return names[0] if outputs == 1 else names

    def model(self, output: str, inputs: list) -> ModelProto:
        self.nodes.append(helper.make_node("Identity", [output], ["y"]))
        out = [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)]
        graph = helper.make_graph(self.nodes, "pool", inputs, out, initializer=self.initializers)
        return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def _weight_inputs(height: int, width: int) -> list:
    value = helper.make_tensor_value_info
    return [
        value("map", TensorProto.FLOAT, [1, None, height, width]),
        value("wy", TensorProto.FLOAT, [None, POOL, height]),
        value("wx", TensorProto.FLOAT, [None, POOL, width]),
    ]


def dense_graph(height: int, width: int, transpose: bool = True, chunks: int = 1) -> ModelProto:
    """The exported form (chunks=1, transpose): (R, C, 7, 7); without ``transpose`` (R, 7, C, 7)."""
    g = Graph()
    map_hcw = g("Reshape", g("Transpose", "map", perm=[0, 2, 1, 3]), g.ints(height, -1))  # (H, C*W)
    channels = g("Shape", "map", start=1, end=2)
    count = g("Shape", "wy", start=0, end=1)
    bounds = _chunk_bounds(g, count, chunks)
    pieces = []
    for start, end in itertools.pairwise(bounds):
        wy, wx = (g("Slice", w, start, end) for w in ("wy", "wx"))
        rows = g("MatMul", g("Reshape", wy, g.ints(-1, height)), map_hcw)  # (K*7, C*W)
        per_roi = g(
            "Reshape", rows, g("Concat", g.ints(-1), g("Mul", channels, g.ints(POOL)), g.ints(width), axis=0)
        )
        pieces.append(g("MatMul", per_roi, g("Transpose", wx, perm=[0, 2, 1])))  # (K, 7*C, 7)
    pooled = g("Concat", *pieces, axis=0) if chunks > 1 else pieces[0]
    pooled = g("Reshape", pooled, g("Concat", count, g.ints(POOL), channels, g.ints(POOL), axis=0))
    if transpose:
        pooled = g("Transpose", pooled, perm=[0, 2, 1, 3])
    return g.model(pooled, _weight_inputs(height, width))


def roi_align_graph(height: int, width: int) -> ModelProto:
    """ONNX's RoiAlign on boxes (R, 4) in the map's half-pixel convention: (R, C, 7, 7)."""
    g = Graph()
    pooled = g(
        "RoiAlign",
        "map",
        "boxes",
        "batch",
        mode="avg",
        output_height=POOL,
        output_width=POOL,
        sampling_ratio=SAMPLING,
        spatial_scale=1 / STRIDE,
        coordinate_transformation_mode="half_pixel",
    )
    value = helper.make_tensor_value_info
    inputs = [
        value("map", TensorProto.FLOAT, [1, None, height, width]),
        value("boxes", TensorProto.FLOAT, [None, 4]),
        value("batch", TensorProto.INT64, [None]),
    ]
    return g.model(pooled, inputs)


def _chunk_bounds(g: Graph, count: str, chunks: int) -> list[str]:
    """(1,) int64 bounds of ``chunks`` near-equal slices of ``count`` (a (1,) shape) rows."""
    return [g("Div", g("Mul", count, g.ints(i)), g.ints(chunks)) for i in range(chunks + 1)]


def _supports(g: Graph) -> dict[str, tuple[str, str]]:
    """Per axis, (first, length) (R,) int64 of each RoI's nonzero weights (length >= 1)."""
    out = {}
    for axis, weights in (("y", "wy"), ("x", "wx")):
        nonzero = g(
            "Cast",
            g("Greater", g("ReduceSum", weights, g.ints(1), keepdims=0), g.const(np.float32(0))),
            to=TensorProto.INT32,
        )
        first = g("ArgMax", nonzero, axis=1, keepdims=0)
        last = g("ArgMax", nonzero, axis=1, keepdims=0, select_last_index=1)
        out[axis] = (first, g("Max", g("Add", g("Sub", last, first), g.ints(1)), g.ints(1)))
    return out


def _unsort(g: Graph, pieces: list[str], order: str, count: str) -> str:
    """Concatenate the chunks (rows in ``order``) and put the rows back in the input order."""
    inverse = g("TopK", g("Neg", order), count, outputs=2, largest=1, sorted=1)[1]
    return g("Gather", g("Concat", *pieces, axis=0), inverse)


def crops_graph(height: int, width: int, chunks: int) -> ModelProto:
    """Sorted per-RoI windows gathered from a channels-last map (module docstring): (R, 7, 7, C)."""
    g = Graph()
    nhwc = g("Transpose", "map", perm=[0, 2, 3, 1])
    cells = g("Flatten", nhwc, axis=3)  # (H*W, C)
    map_hwc = g("Reshape", nhwc, g.ints(height, -1))  # (H, W*C)
    count = g("Shape", "wy", start=0, end=1)
    support = _supports(g)
    order = g("TopK", g("Mul", support["y"][1], support["x"][1]), count, outputs=2, largest=1, sorted=1)[1]
    bounds = _chunk_bounds(g, count, chunks)
    pieces = []
    for i, (start, end) in enumerate(itertools.pairwise(bounds)):
        rois = g("Slice", order, start, end)
        size = g("Shape", rois)
        if i == 0:  # the largest RoIs: no window to gain, the dense form on the map
            rows = g("MatMul", g("Reshape", g("Gather", "wy", rois), g.ints(-1, height)), map_hwc)
            rows = g("Reshape", rows, g("Concat", size, g.ints(POOL, width, -1), axis=0))  # (K, 7, W, C)
            pieces.append(g("MatMul", g("Unsqueeze", g("Gather", "wx", rois), g.ints(1)), rows))
            continue
        window = {}
        for axis, weights, length in (("y", "wy", height), ("x", "wx", width)):
            first, extent = (g("Gather", t, rois) for t in support[axis])
            span = g("ReduceMax", g("Concat", extent, g.ints(1), axis=0), keepdims=1)  # (1,)
            low = g("Min", first, g("Sub", g.ints(length), span))  # the window stays on the map
            steps = g("Range", g.const(np.int64(0)), g("Squeeze", span, g.ints(0)), g.const(np.int64(1)))
            index = g("Add", g("Unsqueeze", low, g.ints(1)), steps)  # (K, span)
            wide = g(
                "Expand", g("Unsqueeze", index, g.ints(1)), g("Concat", size, g.ints(POOL), span, axis=0)
            )
            window[axis] = (index, g("GatherElements", g("Gather", weights, rois), wide, axis=2), span)
        (rows, wy, span_y), (cols, wx, span_x) = window["y"], window["x"]
        flat = g(
            "Add", g("Unsqueeze", g("Mul", rows, g.ints(width)), g.ints(2)), g("Unsqueeze", cols, g.ints(1))
        )
        crop = g("Gather", cells, flat)  # (K, hy, hx, C)
        by_rows = g("MatMul", wy, g("Reshape", crop, g("Concat", size, span_y, g.ints(-1), axis=0)))
        by_rows = g("Reshape", by_rows, g("Concat", size, g.ints(POOL), span_x, g.ints(-1), axis=0))
        pieces.append(g("MatMul", g("Unsqueeze", wx, g.ints(1)), by_rows))  # (K, 7, 7, C)
    return g.model(_unsort(g, pieces, order, count), _weight_inputs(height, width))


def exported_graph(height: int, width: int) -> ModelProto:
    """a3d-export's windowed RoI pooling (RoiAlignGraph, the channel count left dynamic) on inputs
    "map" (1, C, H, W) and "rois" (R, 5)."""
    with tempfile.TemporaryDirectory(prefix="a3d-roi-pool-") as tmp:
        path = os.path.join(tmp, "pool.onnx")
        rois = torch.tensor([[0.0, 10.0, 10.0, 90.0, 60.0], [0.0, 0.0, 5.0, 40.0, 70.0]])
        export_roi_align(path, torch.zeros(1, 4, height, width), rois)
        model = onnx.load(path)
    model.graph.input[0].name = "map"
    for node in model.graph.node:
        node.input[:] = ["map" if name == "features" else name for name in node.input]
    model.graph.output[0].name = "y"
    for node in model.graph.node:
        node.output[:] = ["y" if name == "pooled" else name for name in node.output]
    return model


def random_rois(count: int, height: int, width: int, seed: int = 0) -> np.ndarray:
    """(count, 4) boxes in image pixels on a (height, width)-cell map: log-uniform sizes from
    16 pixels to the whole frame, inside the frame, as proposals are (most small, a few large)."""
    rng = np.random.default_rng(seed)
    frame = np.array([STRIDE * width, STRIDE * height], np.float64)
    size = np.exp(rng.uniform(np.log(16.0), np.log(frame), (count, 2)))
    corner = rng.uniform(0.0, 1.0, (count, 2)) * (frame - size) - 0.5
    return np.hstack([corner, corner + size]).astype(np.float32)


def pooling_inputs(boxes: np.ndarray, feature_map: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Feeds (map, the real row and column weights, boxes for RoiAlign) and torch's pooling (R, C, 7, 7)."""
    rois = torch.cat([torch.zeros(len(boxes), 1), torch.as_tensor(boxes)], 1)
    fmap = torch.as_tensor(feature_map)
    box = (rois[:, 1:5] + 0.5) / STRIDE - 0.5
    wy = _axis_weights(box[:, 1], box[:, 3], fmap.shape[2], POOL, SAMPLING)
    wx = _axis_weights(box[:, 0], box[:, 2], fmap.shape[3], POOL, SAMPLING)
    feeds = {
        "map": feature_map,
        "wy": wy.numpy(),
        "wx": wx.numpy(),
        "boxes": boxes + np.float32(0.5),
        "batch": np.zeros(len(boxes), np.int64),
        "rois": rois.numpy(),
    }
    return feeds, roi_align(fmap, rois, POOL, 1 / STRIDE, SAMPLING).numpy()


def forms(
    height: int, width: int, chunks: int
) -> dict[str, tuple[ModelProto, Callable[[np.ndarray], np.ndarray]]]:
    """name -> (graph, the map from its output to (R, C, 7, 7))."""
    same = lambda y: y  # noqa: E731
    y_c_x = lambda y: y.reshape(len(y), POOL, -1, POOL).transpose(0, 2, 1, 3)  # noqa: E731
    channels_last = lambda y: y.transpose(0, 3, 1, 2)  # noqa: E731
    return {
        "dense (exported before)": (dense_graph(height, width), same),
        "dense, no transpose": (dense_graph(height, width, transpose=False), y_c_x),
        f"dense, {4 * chunks} chunks": (dense_graph(height, width, chunks=4 * chunks), same),
        "ONNX RoiAlign": (roi_align_graph(height, width), same),
        f"crops, {chunks} chunks": (crops_graph(height, width, chunks), channels_last),
        "windows (exported)": (exported_graph(height, width), channels_last),
    }


def _session(model: ModelProto, threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])


def _bound_run(
    session: ort.InferenceSession, feeds: dict[str, np.ndarray], like: np.ndarray
) -> Callable[[], None]:
    """A call of ``session`` writing into one preallocated output: a fresh 50 MB output per call
    would time the page faults of its allocation, which the model's own pooled tensor (reused
    from ONNX Runtime's arena) does not pay. Calls of one form run back to back: between forms
    the machine may reclaim a session's idle arena pages (this one runs kdamond), and the first
    call after that pays their faults, as the dense form's 258 MB intermediate does."""
    binding = session.io_binding()
    for name, value in feeds.items():
        binding.bind_cpu_input(name, value)
    out = np.empty_like(like)
    binding.bind_output("y", "cpu", 0, np.float32, out.shape, out.ctypes.data)

    def run() -> None:
        session.run_with_iobinding(binding)
        assert out.size  # keeps the bound buffer alive as long as the call can run

    return run


def window_cost(
    wy: np.ndarray, wx: np.ndarray, order: np.ndarray, chunks: int, channels: int
) -> tuple[int, int]:
    """(multiply-adds, intermediate floats) of the exported window products when the rows of the
    weights wy (R, 7, H), wx (R, 7, W) come in ``order``: per chunk of K RoIs on an h x w union
    window, K x 7 x h x w x C (rows) + K x 49 x w x C (columns), and the rows' K x 7 x w x C
    output that the columns read back."""
    (first_y, end_y), (first_x, end_x) = (
        (nonzero.argmax(1), nonzero.shape[1] - nonzero[:, ::-1].argmax(1))
        for nonzero in (np.abs(w).sum(1) > 0 for w in (wy, wx))
    )
    bounds = chunk_bounds(len(order), chunks)
    macs = floats = 0
    for start, end in itertools.pairwise(bounds):
        rows = order[start:end]
        if len(rows):
            h = int(end_y[rows].max() - first_y[rows].min())
            w = int(end_x[rows].max() - first_x[rows].min())
            floats += len(rows) * POOL * w * channels
            macs += len(rows) * POOL * w * channels * (h + POOL)
    return macs, floats


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.roi_pool_speed", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--rois", type=int, default=500)
    parser.add_argument("--channels", type=int, default=512, help="fused channels (vgg16-fused: 512)")
    parser.add_argument("--map", default="27x36", help="feature map H x W (427 x 561 / 16: 27 x 36)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--chunks", type=int, default=8, help="chunks of the crops form (dense: 4x)")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    height, width = (int(v) for v in args.map.split("x"))
    feature_map = np.random.default_rng(1).standard_normal((1, args.channels, height, width), np.float32)
    boxes = random_rois(args.rois, height, width)
    start = time.perf_counter()
    order = pooling_order(boxes)
    ordering = time.perf_counter() - start
    feeds, want = pooling_inputs(boxes[order], feature_map)  # in a3d-run's order
    given, _ = pooling_inputs(boxes, feature_map)
    layouts = (("as given", np.arange(len(boxes)), POOL_CHUNKS), ("in a3d-run's order", order, POOL_CHUNKS),
               ("each RoI on its own window", np.arange(len(boxes)), max(len(boxes), 1)))  # fmt: skip
    costs = {name: window_cost(given["wy"], given["wx"], rows, chunks, args.channels)
             for name, rows, chunks in layouts}  # fmt: skip
    runs = {}
    for name, (model, layout) in forms(height, width, args.chunks).items():
        session = _session(model, args.threads)
        mine = {i.name: feeds[i.name] for i in session.get_inputs()}
        got = session.run(None, mine)[0]
        runs[name] = (_bound_run(session, mine, got), float(np.abs(layout(got) - want).max()))
    seconds: dict[str, list[float]] = {name: [] for name in runs}
    start_load = os.getloadavg()
    for _ in range(2):  # two blocks per form, interleaved; each block warms up first (see _bound_run)
        for name, (run, _) in runs.items():
            run()
            for _ in range(args.repeats):
                start = time.perf_counter()
                run()
                seconds[name].append(time.perf_counter() - start)
    load = "load average {:.2f} {:.2f} {:.2f}".format(*start_load) + " -> {:.2f} {:.2f} {:.2f}".format(
        *os.getloadavg()
    )
    print(
        f"RoI pooling of one map, {args.rois} RoIs x {args.channels} channels on {height} x {width}, "
        f"{args.threads} threads ({load}); median of 2 x {args.repeats} calls:"
    )
    print(f"  {'form':28s}{'ms':>9s}  max |diff| vs torch roi_align")
    for name, values in seconds.items():
        print(f"  {name:28s}{1e3 * float(np.median(values)):9.1f}  {runs[name][1]:.1e}")
    print(f"a3d-run's order of these RoIs (runtime.network.roi_order): {1e3 * ordering:.2f} ms")
    print(f"the window products in {POOL_CHUNKS} chunks, multiply-adds and intermediate: "
          + ", ".join(f"{name} {macs / 1e9:.3f} GMAC, {floats / 1e6:.1f} M floats"
                      for name, (macs, floats) in costs.items()))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
