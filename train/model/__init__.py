"""The dual-trunk VGG16 RoI network: trunks, RoI pooling, heads."""

from a3d.train.model.config import PRESETS, NetConfig, preset
from a3d.train.model.net import A3DNet
from a3d.train.model.weights import describe_loaded, load_vgg16_imagenet

__all__ = ["PRESETS", "A3DNet", "NetConfig", "describe_loaded", "load_vgg16_imagenet", "preset"]
