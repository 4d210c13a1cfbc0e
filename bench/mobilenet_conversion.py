"""Convert MobileNetV2 (ImageNet, int8 TFLite) into the ONNX file a3d's 2D classifier runs, once.

    python3 -m venv /tmp/t2o && /tmp/t2o/bin/pip install tflite2onnx==0.4.1 onnxruntime opencv-python-headless
    /tmp/t2o/bin/python -m bench.mobilenet_conversion mobilenet_v2_1.0_224_quant.tflite \\
        imagenet_labels.txt -o runtime/models/mobilenet_v2_imagenet.onnx

The source is google-coral/test_data's ``mobilenet_v2_1.0_224_quant.tflite`` (Apache-2.0) and its
``imagenet_labels.txt`` (1001 lines, "background" first). ``tflite2onnx`` (a development tool, not
a dependency of a3d) writes a float graph that keeps TFLite's quantisation as QuantizeLinear /
DequantizeLinear pairs around float weights (14 MB). This then

- stores each weight as the uint8 tensor its QuantizeLinear makes of it (the TFLite file's own
  int8 weights, so nothing is re-quantised: 3.5 MB), and each Conv bias as the int32 tensor
  TFLite had (scale: input scale x weight scale), both behind a DequantizeLinear; ONNX Runtime
  fuses these into its int8 convolutions;
- takes any batch size (the Reshape before the softmax flattens to (batch, 1001));
- outputs the float softmax (TFLite's last step quantises it to steps of 1/256, too coarse for the
  sums over ImageNet classes a3d reads);
- stores the labels in the metadata (``labels``, one per line) with the source and licence, and
  its initializers and nodes in a fixed order, so that the file is the same on every run.

It checks the written file against tflite2onnx's float graph on crops of ``--image`` (default:
the first sample frame): on each crop every probability within 0.02, so the top-1 class is the
float graph's or one tied with it within that (the top 5 agree up to such near-ties, as printed).
Exit status 1 when a check fails.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import onnx
import onnxruntime as ort
from onnx import helper, numpy_helper

NUM_LABELS = 1001
SIDE = 224
TOLERANCE = 0.02
SOURCE = "google-coral/test_data @ 104342d2, mobilenet_v2_1.0_224_quant.tflite"
ABOUT = (
    "MobileNetV2 1.0 224 (Sandler et al. 2018), trained on ImageNet 1k, int8 (TFLite), converted with "
    "tflite2onnx 0.4.1 and bench.mobilenet_conversion. Input (N, 3, 224, 224) RGB as (value - 128) / 128; "
    "output (N, 1001) softmax, index 0 background. Apache-2.0 (LICENSE-MobileNetV2.txt)."
)


def convert(tflite: Path, labels: list[str]) -> tuple[onnx.ModelProto, onnx.ModelProto]:
    """(tflite2onnx's float graph, the graph a3d ships)."""
    import tflite2onnx  # a development tool only (module docstring)

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "float.onnx"
        tflite2onnx.convert(str(tflite), str(path))
        original = onnx.load(path)
    model = onnx.ModelProto()
    model.CopyFrom(original)
    graph = model.graph
    _fold_weights(graph)
    _quantise_biases(graph)
    _float_softmax(graph)
    _any_batch(graph)
    _any_size(graph)
    _canonical_order(graph)
    del model.metadata_props[:]
    for key, value in (("labels", "\n".join(labels)), ("source", SOURCE), ("about", ABOUT)):
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model)
    return original, model


def _fold_weights(graph: onnx.GraphProto) -> None:
    """Each QuantizeLinear of an initializer replaced by the integer tensor it computes."""
    inits = {t.name: t for t in graph.initializer}
    for node in [n for n in graph.node if n.op_type == "QuantizeLinear" and n.input[0] in inits]:
        weight, scale, zero = (numpy_helper.to_array(inits[name]) for name in node.input[:3])
        info = np.iinfo(zero.dtype)
        q = np.clip(np.round(weight / scale) + zero.astype(np.int64), info.min, info.max).astype(zero.dtype)
        graph.node.remove(node)
        graph.initializer.remove(inits.pop(node.input[0]))
        graph.initializer.append(numpy_helper.from_array(q, node.output[0]))


def _quantise_biases(graph: onnx.GraphProto) -> None:
    """Each Conv's float bias as int32 at input scale x weight scale behind a DequantizeLinear."""
    inits = {t.name: t for t in graph.initializer}
    producer = {n.output[0]: n for n in graph.node}
    for conv in [n for n in graph.node if n.op_type == "Conv" and len(n.input) == 3]:
        scales = [numpy_helper.to_array(inits[producer[name].input[1]]) for name in conv.input[:2]]
        scale = np.float32(scales[0] * scales[1])
        bias = numpy_helper.to_array(inits[conv.input[2]])
        name = conv.input[2]
        graph.initializer.remove(inits.pop(name))
        q = np.round(bias / scale).astype(np.int32)
        graph.initializer.extend([
            numpy_helper.from_array(q, f"{name}_int32"),
            numpy_helper.from_array(np.array(scale, np.float32), f"{name}_scale"),
        ])  # fmt: skip
        dq = helper.make_node("DequantizeLinear", [f"{name}_int32", f"{name}_scale"], [name])
        graph.node.insert(list(graph.node).index(conv), dq)


def _float_softmax(graph: onnx.GraphProto) -> None:
    """The Softmax's float output as the graph's output, its QuantizeLinear / DequantizeLinear dropped."""
    softmax = next(n for n in graph.node if n.op_type == "Softmax")
    for node in [n for n in graph.node if n.input and n.input[0] == softmax.output[0]]:
        follower = next(n for n in graph.node if n.input and n.input[0] == node.output[0])
        graph.node.remove(follower)
        graph.node.remove(node)
    used = {name for n in graph.node for name in n.input}
    for unused in [t for t in graph.initializer if t.name not in used]:
        graph.initializer.remove(unused)
    del graph.output[:]
    graph.output.append(helper.make_tensor_value_info(softmax.output[0], onnx.TensorProto.FLOAT,
                                                      ["batch", NUM_LABELS]))  # fmt: skip


def _any_batch(graph: onnx.GraphProto) -> None:
    """A symbolic batch size: the input's first dimension, and the Reshape before the softmax."""
    graph.input[0].type.tensor_type.shape.dim[0].dim_param = "batch"
    del graph.value_info[:]  # tflite2onnx's shapes fix the batch at 1; ONNX Runtime infers its own
    inits = {t.name: t for t in graph.initializer}
    for node in [n for n in graph.node if n.op_type == "Reshape"]:
        shape = numpy_helper.to_array(inits[node.input[1]]).copy()
        shape[0] = -1
        inits[node.input[1]].CopyFrom(numpy_helper.from_array(shape, node.input[1]))


def _any_size(graph: onnx.GraphProto) -> None:
    """The final 7 x 7 AveragePool as a GlobalAveragePool: the same at 224 x 224, and other input
    sizes run too (a3d's classifier may take smaller crops for speed)."""
    pool = next(n for n in graph.node if n.op_type == "AveragePool")
    pool.op_type = "GlobalAveragePool"
    del pool.attribute[:]
    graph.input[0].type.tensor_type.shape.dim[2].dim_param = "height"
    graph.input[0].type.tensor_type.shape.dim[3].dim_param = "width"


def _canonical_order(graph: onnx.GraphProto) -> None:
    """Initializers by name and nodes in one topological order (of the nodes ready, the first output
    name first): tflite2onnx writes both in an order that changes from run to run, and the file
    should come out the same byte for byte."""
    tensors = sorted((onnx.TensorProto.FromString(t.SerializeToString()) for t in graph.initializer),
                     key=lambda t: t.name)  # fmt: skip
    del graph.initializer[:]
    graph.initializer.extend(tensors)
    nodes = [onnx.NodeProto.FromString(n.SerializeToString()) for n in graph.node]
    producer = {name: i for i, node in enumerate(nodes) for name in node.output}
    needs = [{producer[name] for name in node.input if name in producer} for node in nodes]
    done: list[int] = []
    while len(done) < len(nodes):
        ready = (i for i in range(len(nodes)) if i not in done and needs[i] <= set(done))
        done.append(min(ready, key=lambda i: nodes[i].output[0]))
    del graph.node[:]
    graph.node.extend(nodes[i] for i in done)


def crops(image: np.ndarray) -> np.ndarray:
    """Six (3, 224, 224) inputs from an RGB image: the whole and a 2 x 2 grid plus its centre."""
    h, w = image.shape[:2]
    windows = [(0, 0, w, h), (w // 4, h // 4, 3 * w // 4, 3 * h // 4)]
    windows += [(x, y, x + w // 2, y + h // 2) for x in (0, w // 2) for y in (0, h // 2)]
    out = [cv2.resize(image[y1:y2, x1:x2], (SIDE, SIDE), interpolation=cv2.INTER_AREA)
           for x1, y1, x2, y2 in windows]  # fmt: skip
    return ((np.stack(out).astype(np.float32) - 128.0) / 128.0).transpose(0, 3, 1, 2)


def _session(model: onnx.ModelProto) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.log_severity_level = 3
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])


def check(original: onnx.ModelProto, shipped: onnx.ModelProto, batch: np.ndarray, labels: list[str]) -> bool:
    """Whether ``shipped`` (the whole batch at once) agrees with ``original`` (one crop at a time,
    as tflite2onnx wrote it) on every crop (module docstring); each crop's top 5 printed."""
    session = _session(shipped)
    ours = session.run(None, {session.get_inputs()[0].name: batch})[0]
    float_session = _session(original)
    name = float_session.get_inputs()[0].name
    theirs = np.concatenate([float_session.run(None, {name: crop[None]})[0] for crop in batch])
    ok = True
    for i, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        top_a, top_b = np.argsort(-a)[:5], np.argsort(-b)[:5]
        same = float(np.abs(a - b).max()) <= TOLERANCE and b[top_a[0]] >= b[top_b[0]] - TOLERANCE
        ok &= bool(same)
        shown = ", ".join(f"{labels[j].split(',')[0]} {a[j]:.3f}/{b[j]:.3f}" for j in top_a)
        print(
            f"crop {i}: {'agrees' if same else 'DIFFERS'}, max |dp| {np.abs(a - b).max():.4f}, "
            f"top 5 shared {len(set(top_a) & set(top_b))}/5 (shipped/float): {shown}"
        )
    return ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tflite", type=Path, help="mobilenet_v2_1.0_224_quant.tflite")
    parser.add_argument("labels", type=Path, help="imagenet_labels.txt (1001 lines)")
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--image", type=Path, action="append", help="image(s) to check on")
    args = parser.parse_args(argv)
    labels = args.labels.read_text().splitlines()
    if len(labels) != NUM_LABELS:
        print(f"{args.labels}: expected {NUM_LABELS} labels, got {len(labels)}", file=sys.stderr)
        return 1
    original, shipped = convert(args.tflite, labels)
    ok = True
    for path in args.image or [Path("samples/synth_000000.color.png")]:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            print(f"{path}: cannot read the image", file=sys.stderr)
            return 1
        ok &= check(original, shipped, crops(image[..., ::-1]), labels)
    onnx.save(shipped, args.output)
    size = args.output.stat().st_size / 1e6
    print(f"wrote {args.output} ({size:.1f} MB); checks {'passed' if ok else 'FAILED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
