"""ImageNet VGG16 initialisation of A3DNet from a local file in torchvision's key layout.

The file is a state dict as ``torch.save(torchvision.models.vgg16(weights=...).state_dict())``
writes it: ``features.N.weight/bias`` for the 13 convs (N = 0, 2, 5, 7, 10, 12, 14, 17, 19, 21,
24, 26, 28), ``classifier.0`` (fc6, 4096 x 25088 = 512 x 7 x 7 flattened (C, y, x)),
``classifier.3`` (fc7, 4096 x 4096); ``classifier.6`` (the 1000 ImageNet classes) is not used.
Nothing is downloaded: without a file, A3DNet keeps its own clean init.

What goes where (docs/conventions.md "Network": both trunks start from ImageNet VGG16):
- Both trunks get the same conv weights. conv1_1 is converted to our input convention
  (a3d.runtime.network.preprocess: BGR, 0..255 minus the Caffe mean) when the file is torchvision's
  (RGB, /255, minus mean, / std): channels reversed and divided by 255 * std. The two
  conventions' means differ by under one grey level; that offset is ignored.
  ``input_convention="caffe"`` loads conv1_1 as is (Caffe VGG16 converted to this layout).
- Width-scaled trunks take the leading output/input channel slice of every conv, times
  (file input channels / model input channels): a heuristic that keeps pre-activations at
  the full network's scale instead of shrinking them by ``width`` at every layer.
- fc6: the ImageNet fc6 expects one 512 x 7 x 7 block; A3DNet's fc6 sees ``pooled_blocks``
  blocks of ``block_channels`` x 7 x 7. Each block's weights are the leading slice of
  classifier.0 (rows :fc6, channels :block_channels, scaled as the convs) divided by the number
  of blocks, so on identical blocks fc6 answers ImageNet's fc6 of one block. fc7 takes the
  leading slice of classifier.3, scaled likewise. fc6 and fc7 are left at their clean init when
  the shapes do not allow a slice (pool_size != 7, more fc6/fc7 units or block channels than the
  file has); the returned names say what was loaded. BatchNorm, fusion convs and heads keep
  their own init.
"""

from __future__ import annotations

import pickle
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import torch

from a3d.train.model.net import A3DNet

IMAGENET_POOL = 7
TORCHVISION_STD_RGB = (0.229, 0.224, 0.225)
InputConvention = Literal["torchvision", "caffe"]
TRUNKS = ("color", "depth")
IMAGENET_VGG16_NOTICE = (
    "ImageNet VGG16 convolution weights by Karen Simonyan and Andrew Zisserman, 'Very Deep "
    "Convolutional Networks for Large-Scale Image Recognition' (ICLR 2015), licensed CC BY 4.0 "
    "(https://creativecommons.org/licenses/by/4.0/); used as initialisation, unchanged where frozen"
)


def _tensor(vgg: Mapping[str, torch.Tensor], key: str, ndim: int, source: str) -> torch.Tensor:
    if key not in vgg:
        raise ValueError(f"{source}: missing key {key!r} (expected a torchvision VGG16 state dict)")
    value = vgg[key]
    if not isinstance(value, torch.Tensor) or value.dim() != ndim:
        shape = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
        raise ValueError(f"{source}: {key!r} is {shape}, expected a {ndim}-d tensor")
    return value


def _leading(value: torch.Tensor, shape: torch.Size, key: str, source: str) -> torch.Tensor:
    """value[:shape[0], :shape[1], ...], or a clear error when value is too small."""
    if any(have < need for have, need in zip(value.shape, shape, strict=True)):
        raise ValueError(f"{source}: {key!r} has shape {tuple(value.shape)}, the model needs {tuple(shape)}")
    return value[tuple(slice(0, n) for n in shape)]


def _first_conv_scale(weight: torch.Tensor) -> torch.Tensor:
    std = torch.tensor(TORCHVISION_STD_RGB, dtype=weight.dtype, device=weight.device)
    return (255.0 * std)[None, :, None, None]


def caffe_first_conv(weight: torch.Tensor) -> torch.Tensor:
    """torchvision conv1_1 (RGB, (x/255 - mean)/std) -> weights for BGR 0..255 inputs."""
    return (weight / _first_conv_scale(weight)).flip(1)


def torchvision_first_conv(weight: torch.Tensor) -> torch.Tensor:
    """The inverse of ``caffe_first_conv``: conv1_1 for BGR 0..255 inputs -> torchvision's convention,
    so that a file written with it loads back to the same weights."""
    return weight.flip(1) * _first_conv_scale(weight)


def _trunk_entries(
    model: A3DNet,
    vgg: Mapping[str, torch.Tensor],
    source: str,
    convention: InputConvention,
    trunks: tuple[str, ...],
) -> dict[str, torch.Tensor]:
    entries: dict[str, torch.Tensor] = {}
    for trunk_name in trunks:
        trunk = getattr(model, f"{trunk_name}_trunk")
        if trunk is None:
            continue
        for index, conv in trunk.convs():
            key = f"features.{index}"
            weight = _tensor(vgg, f"{key}.weight", 4, source)
            if weight.shape[2:] != conv.weight.shape[2:]:
                shape = tuple(weight.shape)
                raise ValueError(f"{source}: {key}.weight has shape {shape}, expected 3x3 kernels")
            if index == 0 and convention == "torchvision":
                weight = caffe_first_conv(weight)
            scale = weight.shape[1] / conv.weight.shape[1]
            name = f"{trunk_name}_trunk.features.{index}"
            entries[f"{name}.weight"] = _leading(weight, conv.weight.shape, f"{key}.weight", source) * scale
            bias = _tensor(vgg, f"{key}.bias", 1, source)
            entries[f"{name}.bias"] = _leading(bias, conv.bias.shape, f"{key}.bias", source)
    return entries


def _fc_entries(model: A3DNet, vgg: Mapping[str, torch.Tensor], source: str) -> dict[str, torch.Tensor]:
    if not any(key.startswith("classifier.") for key in vgg):
        return {}  # a convolutions-only file (a3d-vgg16-weights): fc6/fc7 keep their own init
    fc6_w = _tensor(vgg, "classifier.0.weight", 2, source)
    fc6_b = _tensor(vgg, "classifier.0.bias", 1, source)
    fc7_w = _tensor(vgg, "classifier.3.weight", 2, source)
    fc7_b = _tensor(vgg, "classifier.3.bias", 1, source)
    cells = IMAGENET_POOL**2
    if fc6_w.shape[1] % cells:
        raise ValueError(f"{source}: 'classifier.0.weight' has {fc6_w.shape[1]} inputs, not C x 7 x 7")
    file_channels = fc6_w.shape[1] // cells
    units6, units7 = model.fc6.out_features, model.fc7.out_features
    blocks, channels = model.pooled_blocks, model.block_channels
    if (
        model.config.pool_size != IMAGENET_POOL
        or units6 > min(fc6_w.shape[0], fc6_b.shape[0], fc7_w.shape[1])
        or units7 > min(fc7_w.shape[0], fc7_b.shape[0])
        or channels > file_channels
    ):
        return {}
    block = fc6_w.reshape(-1, file_channels, IMAGENET_POOL, IMAGENET_POOL)[:units6, :channels]
    block = block.reshape(units6, -1) * (file_channels / channels) / blocks
    return {
        "fc6.weight": block.repeat(1, blocks),
        "fc6.bias": fc6_b[:units6],
        "fc7.weight": fc7_w[:units7, :units6] * (fc7_w.shape[1] / units6),
        "fc7.bias": fc7_b[:units7],
    }


def imagenet_init_state(
    model: A3DNet,
    vgg: Mapping[str, torch.Tensor],
    source: str,
    input_convention: InputConvention = "torchvision",
    trunks: tuple[str, ...] = TRUNKS,
) -> dict[str, torch.Tensor]:
    """Model state entries (parameter name -> tensor) derived from a torchvision VGG16 state dict.

    Pure shape logic plus slicing, so it also runs on meta tensors. source names the file in
    error messages; ``trunks`` names the trunks to initialise ("color", "depth"). A file without
    ``classifier.*`` keys (convolutions only) leaves fc6/fc7 at their own init.
    """
    if input_convention not in ("torchvision", "caffe"):
        raise ValueError(f"input_convention must be 'torchvision' or 'caffe', got {input_convention!r}")
    unknown = set(trunks) - set(TRUNKS)
    if unknown:
        raise ValueError(f"unknown trunk {sorted(unknown)[0]!r} (known: {', '.join(TRUNKS)})")
    return {**_trunk_entries(model, vgg, source, input_convention, trunks), **_fc_entries(model, vgg, source)}


def load_vgg16_imagenet(
    model: A3DNet,
    path: str | Path,
    input_convention: InputConvention = "torchvision",
    trunks: tuple[str, ...] = TRUNKS,
) -> list[str]:
    """Copy ImageNet VGG16 weights from ``path`` into ``model``; returns the parameter names set."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: VGG16 weights file not found")
    try:
        vgg = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError) as error:
        raise ValueError(f"{path}: not a torch state dict file ({error})") from None
    if not isinstance(vgg, Mapping):
        raise ValueError(f"{path}: holds a {type(vgg).__name__}, expected a VGG16 state dict")
    entries = imagenet_init_state(model, vgg, str(path), input_convention, trunks)
    state = model.state_dict()
    with torch.no_grad():
        for name, value in entries.items():
            state[name].copy_(value)
    return list(entries)


def describe_loaded(model: A3DNet, loaded: list[str], source: str | Path) -> str:
    """One line for the log: which of the model's layers came from the file and which kept their init."""
    groups = {
        f"{name} trunk": [f"{name}_trunk.features.{i}.weight" for i, _ in trunk.convs()]
        for name in TRUNKS
        if (trunk := getattr(model, f"{name}_trunk")) is not None
    }
    groups.update(fc6=["fc6.weight"], fc7=["fc7.weight"])
    counts = {group: sum(key in set(loaded) for key in keys) for group, keys in groups.items()}
    got = [f"{group} ({n} of {len(groups[group])})" for group, n in counts.items() if n]
    kept = [group for group, n in counts.items() if not n] + ["BatchNorm, fusion convs and heads"]
    return f"{source}: loaded {', '.join(got) or 'nothing'}; own initialisation kept: {', '.join(kept)}"
