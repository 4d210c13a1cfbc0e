"""The dual-trunk VGG16 RoI network: trunks, RoI pooling, heads.

The configuration (``NetConfig``, the presets) imports without torch; the network and its
weights are loaded on first use (``a3d.train.model.A3DNet``), so a command's --help, which lists
the presets, works without the 'train' extra.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from a3d.train.model.config import PRESETS, NetConfig, preset

if TYPE_CHECKING:
    from a3d.train.model.net import A3DNet
    from a3d.train.model.weights import describe_loaded, load_vgg16_imagenet

_LAZY = {
    "A3DNet": "a3d.train.model.net",
    "describe_loaded": "a3d.train.model.weights",
    "load_vgg16_imagenet": "a3d.train.model.weights",
}

__all__ = ["PRESETS", "A3DNet", "NetConfig", "describe_loaded", "load_vgg16_imagenet", "preset"]


def __getattr__(name: str) -> Any:
    """A3DNet and the weight loaders, imported (with torch) when first asked for."""
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

