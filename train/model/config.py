"""Typed configuration of the dual-trunk RoI network (A3DNet) and its named presets.

``NetConfig()`` is the paper's network (docs/conventions.md "Network"): two full-width VGG16 trunks, the
four pooled 512x7x7 blocks (RoI and context box, colour and depth) concatenated into fc6, fc6/fc7
of 4096. Presets for CPU training scale the trunk channels and the fc sizes down and fuse the
channels before pooling (``fuse_channels``, see a3d.train.model.net) — a departure from the
paper that changes the head's cost, not the trunks'. Torch-free, so that the commands can list
the presets in their --help without the 'train' extra.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal


def scaled_channels(channels: int, width: float) -> int:
    """Channels of a width-scaled layer: round(channels * width), at least 1."""
    return max(1, round(channels * width))


@dataclass(frozen=True)
class NetConfig:
    """Architecture of A3DNet.

    width: trunk channel scale; 1.0 is VGG16's exact layout (64 .. 512 channels), 0.5 / 0.25 /
        0.125 keep the layer layout with ``round(c * width)`` channels per layer.
    trunk_norm: BatchNorm after every trunk conv (a departure, for from-scratch training on
        synthetic data; folded into the convs at export, see a3d.train.model.vgg).
    color_width, color_norm: the colour trunk's own width and BatchNorm (None: ``width`` and
        ``trunk_norm``), so that a full-width ImageNet colour trunk (plain, as ImageNet trained it)
        can sit beside a small depth trunk trained from scratch.
    use_depth: False is the colour-only ablation (one trunk; the depth input is ignored).
    use_context: False drops the context-box pooling (the context RoIs are ignored).
    fuse_channels: None = the paper's plain concatenation of the pooled conv5_3 blocks; an int F =
        a linear 1x1 conv (trunk maps concatenated -> F channels, one for the RoI, one for the
        context box) applied before pooling, so only two F-channel maps are pooled.
    fc6, fc7: widths of the two fully connected layers (each followed by BatchNorm, ReLU, dropout).
    dropout: dropout probability after fc6 and fc7.
    pool_size: RoI pooling output is pool_size x pool_size per channel (ImageNet fc6 needs 7).
    sampling_ratio: bilinear samples per pooling bin along each axis (fixed, so pooling is
        separable and exports with standard ONNX ops).
    roi_pool: "align" (bilinear RoIAlign, a3d's departure; exportable) or "max" (the paper's max RoI
        pooling, for training and the ablation only: a3d-export refuses it). See roi_pool.py.
    """

    width: float = 1.0
    trunk_norm: bool = False
    color_width: float | None = None
    color_norm: bool | None = None
    use_depth: bool = True
    use_context: bool = True
    fuse_channels: int | None = None
    fc6: int = 4096
    fc7: int = 4096
    dropout: float = 0.5
    pool_size: int = 7
    sampling_ratio: int = 2
    roi_pool: Literal["align", "max"] = "align"

    def __post_init__(self) -> None:
        for name in ("width", "color_width"):
            value = getattr(self, name)
            if value is not None and not 0.0 < value <= 1.0:
                raise ValueError(f"NetConfig.{name} must be in (0, 1], got {value}")
        for name in ("fc6", "fc7", "pool_size", "sampling_ratio"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"NetConfig.{name} must be a positive integer, got {getattr(self, name)}")
        if self.fuse_channels is not None and self.fuse_channels < 1:
            raise ValueError(f"NetConfig.fuse_channels must be None or positive, got {self.fuse_channels}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"NetConfig.dropout must be in [0, 1), got {self.dropout}")
        if self.roi_pool not in ("align", "max"):
            raise ValueError(f"NetConfig.roi_pool must be 'align' or 'max', got {self.roi_pool!r}")


    @property
    def color_trunk_width(self) -> float:
        return self.width if self.color_width is None else self.color_width

    @property
    def color_trunk_norm(self) -> bool:
        return self.trunk_norm if self.color_norm is None else self.color_norm


def _fused_preset(width: float, fc: int) -> NetConfig:
    """Width-scaled trunks, fused to the trunk's own conv5_3 width (halves fc6's input)."""
    return NetConfig(width=width, fuse_channels=scaled_channels(512, width), fc6=fc, fc7=fc)


PRESETS: Mapping[str, NetConfig] = MappingProxyType(
    {
        "vgg16": NetConfig(),
        "vgg16-fused": _fused_preset(1.0, 4096),
        "cpu-half": _fused_preset(0.5, 2048),
        "cpu-quarter": _fused_preset(0.25, 1024),
        "cpu-eighth": _fused_preset(0.125, 512),
    }
)


def preset(name: str) -> NetConfig:
    """The named configuration; ValueError lists the known names."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown network preset {name!r} (known: {', '.join(PRESETS)})") from None
