"""Fold an older export's pooled-map Transpose into fc6, without the checkpoint.

    python -m a3d.export.refold MODEL -o OUT

Models exported before ``fold_pool_layout`` (a3d.export.roi_pool_onnx) end each map's RoI
pooling with a Transpose of the pooled maps from (R, y, c, x) to (R, c, y, x), then flatten
them, join them and feed fc6: at 500 RoIs that is a copy of every pooled value (6 ms of the
bundled model's 30 ms head on 2 cores, docs/edge-speed.md). This tool drops those Transposes,
permutes fc6's weight columns to the (y, c, x) order instead (the int8 weights themselves; their
per-row scales are untouched), and moves fc6's input quantisation above the joins
(a3d.export.quantize.quantize_before_layout). fc6 then sums the same products in another order:
the answers are the same, which the tool checks on random inputs before it writes the file with
its metadata (content digest renewed, ``pool_chunks`` 1, the change recorded under
``provenance["refold"]``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from a3d.export.base import ExportError
from a3d.runtime.cli.common import a3d_version, command
from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.extras import Needs

PROG = "python -m a3d.export.refold"
NEEDS = Needs("train", ("onnx",))
TOLERANCE = 1e-5  # of the largest output, per output (the sums are the same; only their order changes)


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0], needs=NEEDS)
    p.add_argument("model", type=Path, help="the model file to refold (model.onnx)")
    p.add_argument("-o", "--output", type=Path, required=True, help="the refolded model file to write")
    return p


def refold_graph(model):
    """``model`` (an onnx.ModelProto, changed in place) without its pooled-map Transposes before fc6;
    ExportError where it has none (already folded, or not an a3d graph)."""
    from onnx import numpy_helper

    from a3d.export.quantize import producer_through, quantize_before_layout

    graph = model.graph
    producers = {out: n for n in graph.node for out in n.output}
    initializers = {i.name: i for i in graph.initializer}
    fc6 = _fc6(graph, producers)
    join = producer_through(producers, fc6.input[0], ("DequantizeLinear", "QuantizeLinear"))
    if join is None or join.op_type != "Concat":
        raise ExportError("no joined pooled maps before fc6 (not an a3d graph)")
    transposes = []
    for name in join.input:
        flatten = producers.get(name)
        transpose = producers.get(flatten.input[0]) if flatten is not None else None
        if flatten is None or flatten.op_type != "Reshape" or not _is_pool_transpose(transpose):
            raise ExportError("no pooled-map Transpose before fc6 (already folded by fold_pool_layout?)")
        transposes.append((flatten, transpose))
    weight = _weight(graph, producers, initializers, fc6.input[1])
    values = numpy_helper.to_array(weight)  # (fc6, K): Gemm with transB = 1
    size = _pool_size(graph, producers, transposes[0][1])
    blocks = len(transposes)
    channels = values.shape[1] // (blocks * size * size)
    order = np.arange(values.shape[1]).reshape(blocks, channels, size, size).transpose(0, 2, 1, 3).reshape(-1)
    weight.CopyFrom(numpy_helper.from_array(np.ascontiguousarray(values[:, order]), weight.name))
    for flatten, transpose in transposes:
        flatten.input[0] = transpose.input[0]
        graph.node.remove(transpose)
    return quantize_before_layout(model)


def _fc6(graph, producers):
    """The first Gemm (fc6): the head's first fully connected layer, B transposed (N, K)."""
    gemm = next((n for n in graph.node if n.op_type == "Gemm"), None)
    if gemm is None or not any(a.name == "transB" and a.i == 1 for a in gemm.attribute):
        raise ExportError("no fc6 Gemm with transposed weights (not an a3d graph)")
    return gemm


def _is_pool_transpose(node) -> bool:
    if node is None or node.op_type != "Transpose":
        return False
    return next((list(a.ints) for a in node.attribute if a.name == "perm"), None) == [0, 2, 1, 3]


def _weight(graph, producers, initializers, name: str):
    """fc6's weight initializer: the int8 one behind a DequantizeLinear, or the float one."""
    dequantize = producers.get(name)
    if dequantize is not None:
        per_row = all(a.i == 0 for a in dequantize.attribute if a.name == "axis")
        if dequantize.op_type != "DequantizeLinear" or not per_row:
            raise ExportError("fc6's weights are not a per-row int8 initializer or a float one")
        name = dequantize.input[0]
    if name not in initializers:
        raise ExportError("fc6's weights are not an initializer")
    return initializers[name]


def _pool_size(graph, producers, transpose) -> int:
    """P of the pooled (R, P, C, P) maps: the reshape that made the Transpose's input."""
    from onnx import numpy_helper

    reshape = producers.get(transpose.input[0])
    shape_name = reshape.input[1] if reshape is not None and reshape.op_type == "Reshape" else None
    constant = producers.get(shape_name)
    if constant is not None and constant.op_type == "Constant":
        shape = numpy_helper.to_array(constant.attribute[0].t)
    else:  # only the shape's own initializer is read, not every weight of the model
        shape = next((numpy_helper.to_array(i) for i in graph.initializer if i.name == shape_name), None)
    if shape is None or len(shape) != 4 or shape[1] != shape[3]:
        raise ExportError("the pooled maps' shape (R, P, C, P) is not a constant of the graph")
    return int(shape[1])


def _answers(path: Path, seed: int = 0) -> list[np.ndarray]:
    """The model's outputs on one random image of 96 x 128 and 60 random RoIs."""
    from a3d.runtime.network.model import DetectorModel

    model = DetectorModel.load(path, threads=1)
    rng = np.random.default_rng(seed)
    color, depth = (rng.uniform(-100, 100, (3, 96, 128)).astype(np.float32) for _ in range(2))
    corner = rng.uniform(0, 100, (60, 2))
    rois = np.hstack([corner, corner + rng.uniform(4, 60, (60, 2))]).astype(np.float32)
    return list(model.run(color, depth, rois, rois * np.float32(1.2)))


@command(PROG, errors=(ExportError,))
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import onnx

    from a3d.export.onnx_export import save_model
    from a3d.runtime.io.atomic import atomic_write_bytes
    from a3d.runtime.network.model import DetectorModel

    metadata = DetectorModel.load(args.model, threads=1).metadata  # ModelError: one line, exit 2
    try:
        model = refold_graph(onnx.load(str(args.model)))
    except ExportError as e:
        raise ExportError(f"{args.model}: {e}") from None
    record = {"date": datetime.now(UTC).isoformat(timespec="seconds"), "a3d": a3d_version(),
              "change": "pooled-map Transposes folded into fc6's weight columns; fc6's input "
                        "quantised before the joins"}  # fmt: skip
    # these graphs pool all RoIs at once or sort them themselves: the caller's order does not matter
    provenance = {**metadata.provenance, "refold": record}
    metadata = dataclasses.replace(metadata, pool_chunks=1, provenance=provenance)
    with tempfile.TemporaryDirectory(prefix="a3d-refold-") as tmp:
        candidate = Path(tmp) / "model.onnx"
        save_model(model, metadata, candidate)
        for before, after in zip(_answers(args.model), _answers(candidate), strict=True):
            if np.abs(after - before).max() > TOLERANCE * max(np.abs(before).max(), 1.0):
                raise ExportError(f"{args.model}: the refolded model answers differently; nothing written")
        atomic_write_bytes(args.output, candidate.read_bytes())  # the bytes that were checked
    print(f"{PROG}: wrote {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
