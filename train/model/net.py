"""A3DNet: the dual-trunk VGG16 RoI network of Deng & Latecki (docs/conventions.md "Network").

colour (B,3,H,W) -> VGG16 trunk -> conv5_3 --+
                                              +-> concat (B, T*C, H/16, W/16)   ("trunk features")
depth  (B,3,H,W) -> VGG16 trunk -> conv5_3 --+
    -> 7x7 RoIAlign (or max RoI pooling) of each RoI and of its context box (roi_pool.py)
    -> fc6 -> BN -> ReLU -> dropout -> fc7 -> BN -> ReLU -> dropout
    -> cls_score (20 logits), bbox_pred_3d (20 x 7 deltas), bbox_pred_2d (20 x 4 deltas)

Pooled-feature layout (NetConfig.fuse_channels):
- None (the default, the paper's): the RoI and the context box are each pooled from the
  concatenated conv5_3 maps and flattened, so fc6 sees the blocks [colour RoI, depth RoI,
  colour context, depth context] (each C x 7 x 7, flattened (C, y, x) like torchvision).
- F (a departure, used by the CPU presets): a linear 1x1 conv maps the concatenated maps to F
  channels for the RoI and another for the context box before pooling, and fc6 sees
  [RoI F x 7 x 7, context F x 7 x 7]. Pooling is linear, so this equals a 1x1 conv on the pooled
  blocks, i.e. a fc6 constrained to a low-rank channel mixing; it halves fc6's input at F = C and
  pools F channels instead of 2C (docs/platform.md "Compute ceilings"). The fuse convs start as the
  average of the two trunks' leading min(F, C) channels, so ImageNet fc6 weights still apply.

Heads follow the release's names; the 3D deltas are docs/conventions.md "Regression targets" (raw after the
statistics are folded in), the 2D deltas are Fast R-CNN deltas toward the amodal 2D box.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import torch
from torch import nn

from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.train.model.config import NetConfig
from a3d.train.model.roi_pool import pooling_rows, roi_align, roi_max_pool, roi_weights
from a3d.train.model.vgg import FEATURE_STRIDE, VGG16Trunk

BOX2D_SIZE = 4


class A3DNet(nn.Module):
    """forward(color, depth, rois, context_rois) -> (class_logits, deltas3d, deltas2d).

    color, depth: (B, 3, H, W) from a3d.runtime.network.preprocess (depth ignored without use_depth).
    rois, context_rois: (R, 5) rows [batch_index, x1, y1, x2, y2] in the README's pixel
    coordinates (context_rois ignored without use_context).
    Returns class_logits (R, 20) (softmax index 0 = background), deltas3d (R, 20*7) and
    deltas2d (R, 20*4), class k's deltas at [k*7 : k*7+7] and [k*4 : k*4+4].
    """

    def __init__(self, config: NetConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or NetConfig()
        self.color_trunk = VGG16Trunk(config.color_trunk_width, config.color_trunk_norm)
        self.depth_trunk = VGG16Trunk(config.width, config.trunk_norm) if config.use_depth else None
        self.trunk_channels = [t.out_channels for t in (self.color_trunk, self.depth_trunk) if t is not None]
        trunk_channels = sum(self.trunk_channels)
        boxes = 2 if config.use_context else 1
        if config.fuse_channels is None:
            if len(set(self.trunk_channels)) > 1:
                raise ValueError("NetConfig: trunks of different widths need fuse_channels (a block per "
                                 "trunk in fc6 assumes one width)")  # fmt: skip
            self.fuse_roi = self.fuse_context = None
            self.block_channels = self.color_trunk.out_channels
            self.pooled_blocks = boxes * (2 if config.use_depth else 1)
        else:
            self.fuse_roi = self._fuse_conv(trunk_channels, config.fuse_channels)
            self.fuse_context = (
                self._fuse_conv(trunk_channels, config.fuse_channels) if config.use_context else None
            )
            self.block_channels = config.fuse_channels
            self.pooled_blocks = boxes
        pooled = self.pooled_blocks * self.block_channels * config.pool_size**2
        self.fc6 = nn.Linear(pooled, config.fc6)
        self.bn6 = nn.BatchNorm1d(config.fc6)
        self.fc7 = nn.Linear(config.fc6, config.fc7)
        self.bn7 = nn.BatchNorm1d(config.fc7)
        self.dropout = nn.Dropout(config.dropout)
        self.cls_score = nn.Linear(config.fc7, NUM_OUTPUTS)
        self.bbox_pred_3d = nn.Linear(config.fc7, NUM_OUTPUTS * BOX_DIM)
        # The export's pooling product (a3d.export.roi_pool_onnx.fold_pool_layout): pooled maps
        # flattened (y, c, x) through it, fc6 permuted to match; None: roi_align, (c, y, x).
        self.pool_product: Callable | None = None
        self.bbox_pred_2d = nn.Linear(config.fc7, NUM_OUTPUTS * BOX2D_SIZE)
        self.norms_frozen = False  # freeze_norms
        # torchvision's VGG classifier init for fc6/fc7, Fast R-CNN's for the heads.
        for layer, std in ((self.fc6, 0.01), (self.fc7, 0.01), (self.cls_score, 0.01),
                           (self.bbox_pred_3d, 0.001), (self.bbox_pred_2d, 0.001)):  # fmt: skip
            nn.init.normal_(layer.weight, std=std)
            nn.init.zeros_(layer.bias)

    def freeze_color(self, convs: int) -> None:
        """Keep the colour trunk's first ``convs`` convolutions fixed (no gradient, no weight decay).

        A frozen layer must be plain (no BatchNorm, whose statistics train mode would still update).
        """
        norm = self.config.color_trunk_norm
        _freeze(self.color_trunk, convs, norm, "solver.freeze_color", "net.color_norm")

    def freeze_depth(self, convs: int) -> None:
        """The same for the depth trunk's first ``convs``: a fine-tune on a few hundred frames of
        one room moves the late layers only (SolverConfig.freeze_depth)."""
        if self.depth_trunk is None:
            if convs:
                raise ValueError("solver.freeze_depth: the network has no depth trunk (net.use_depth=false)")
            return
        _freeze(self.depth_trunk, convs, self.config.trunk_norm, "solver.freeze_depth", "net.trunk_norm")

    def freeze_norms(self) -> None:
        """Keep every BatchNorm in eval mode from now on, also in ``train()``: their running
        statistics stay fixed (SolverConfig.frozen_norms)."""
        self.norms_frozen = True
        self.train(self.training)

    def train(self, mode: bool = True) -> A3DNet:
        super().train(mode)
        if self.norms_frozen:
            for module in self.modules():
                if isinstance(module, nn.modules.batchnorm._BatchNorm):
                    module.eval()
        return self

    @property
    def color_frozen(self) -> bool:
        """Whether the whole colour trunk is fixed, so its output can be computed once per frame."""
        return not any(p.requires_grad for p in self.color_trunk.parameters())

    def _fuse_conv(self, in_channels: int, out_channels: int) -> nn.Conv2d:
        """1x1 conv starting as the per-channel mean of the trunks (each trunk's leading channels,
        zeros elsewhere)."""
        conv = nn.Conv2d(in_channels, out_channels, 1)
        trunks = len(self.trunk_channels)
        with torch.no_grad():
            conv.weight.zero_()
            conv.bias.zero_()
            start = 0
            for channels in self.trunk_channels:
                shared = min(out_channels, channels)
                conv.weight[:shared, start : start + shared, 0, 0] += torch.eye(shared) / trunks
                start += channels
        return conv

    def trunk_features(
        self, color: torch.Tensor | None, depth: torch.Tensor | None, color_map: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Concatenated conv5_3 maps (B, sum C, ceil(H/16), ceil(W/16)), colour channels first.

        ``color_map``: the colour trunk's output computed beforehand (a frozen trunk's cached
        features, a3d.train.color_features), in place of running the trunk on ``color``.
        """
        if color_map is None:
            if color is None:
                raise ValueError("A3DNet: neither a colour image nor the colour trunk's features were given")
            color_map = self.color_trunk(color)
        if self.depth_trunk is None:
            return color_map
        if depth is None:
            raise ValueError("A3DNet: this network uses depth (use_depth=True) but no depth input was given")
        return torch.cat([color_map, self.depth_trunk(depth)], dim=1)

    def head(
        self, features: torch.Tensor, rois: torch.Tensor, context_rois: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pool the RoIs (and context boxes) from trunk_features' output and run fc6 .. heads."""
        config = self.config
        boxes = [(self.fuse_roi, rois)]
        if config.use_context:
            if context_rois is None:
                raise ValueError("A3DNet: this network uses context (use_context=True) but no context_rois")
            boxes.append((self.fuse_context, context_rois))
        if config.roi_pool == "max":
            pool = partial(roi_max_pool, output_size=config.pool_size, spatial_scale=1.0 / FEATURE_STRIDE)
        elif self.pool_product is not None:
            pool = partial(self._pool_for_export, product=self.pool_product)
        else:
            pool = partial(
                roi_align,
                output_size=config.pool_size,
                spatial_scale=1.0 / FEATURE_STRIDE,
                sampling_ratio=config.sampling_ratio,
            )
        pooled = [pool(features if f is None else f(features), box_rois).flatten(1) for f, box_rois in boxes]
        x = torch.cat(pooled, dim=1) if len(pooled) > 1 else pooled[0]
        x = self.dropout(torch.relu(self.bn6(self.fc6(x))))
        x = self.dropout(torch.relu(self.bn7(self.fc7(x))))
        return self.cls_score(x), self.bbox_pred_3d(x), self.bbox_pred_2d(x)

    def _pool_for_export(self, features: torch.Tensor, rois: torch.Tensor, product: Callable) -> torch.Tensor:
        """RoIAlign through ``product`` (separable_pool's contract), in its (R, y, C, x) layout."""
        config = self.config
        weights = roi_weights(features, rois, config.pool_size, 1.0 / FEATURE_STRIDE, config.sampling_ratio)
        return product(pooling_rows(features), *weights)

    def forward(
        self,
        color: torch.Tensor,
        depth: torch.Tensor | None,
        rois: torch.Tensor,
        context_rois: torch.Tensor | None,
        color_map: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.head(self.trunk_features(color, depth, color_map), rois, context_rois)


def _freeze(trunk: VGG16Trunk, convs: int, norm: bool, setting: str, norm_setting: str) -> None:
    """``trunk``'s first ``convs`` convolutions without gradients; ValueError naming ``setting``
    for a count out of range or a trunk with BatchNorms."""
    trunk_convs = trunk.convs()
    if not 0 <= convs <= len(trunk_convs):
        raise ValueError(f"{setting}={convs}: expected 0 .. {len(trunk_convs)} convolutions")
    if convs and norm:
        raise ValueError(f"{setting}: a frozen trunk must be plain ({norm_setting}=false)")
    for _, conv in trunk_convs[:convs]:
        conv.requires_grad_(False)
