"""VGG16 convolutional trunk (conv1_1 .. conv5_3, four max-pools, stride 16), optionally width-scaled.

The module indices of ``VGG16Trunk.features`` are torchvision's ``vgg16().features`` indices
(convs at 0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28), so ImageNet weights in torchvision's
key layout map one to one; pool5 (index 30) is left out, as in Fast R-CNN.

The max-pools round up (``ceil_mode=True``), as Caffe's do (the paper's release is Caffe): the
conv5_3 map of a 427 x 561 image is 27 x 36 and covers the whole image (27 * 16 >= 427), where
torchvision's floor rounding gives 26 x 35 and drops the last 11 rows and 17 columns.

``batch_norm=True`` (a departure from the paper, for training from scratch) puts a BatchNorm2d
between each conv and its ReLU *inside the ReLU's slot*: module N+1 becomes ``Sequential(BN, ReLU)``,
so the convs keep torchvision's indices and ImageNet weights still load. ``fold_batch_norms``
turns an eval-mode trunk back into the plain layout (BN folded into the conv), which is what is
exported.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from a3d.train.model.config import scaled_channels

# Conv output channels, "M" = 2x2 max-pool with stride 2.
VGG16_LAYOUT: tuple[int | str, ...] = (
    64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512,
)  # fmt: skip
FEATURE_STRIDE = 16  # image pixels per conv5_3 cell
VGG16_CONV5_CHANNELS = 512


def conv5_size(height: int, width: int) -> tuple[int, int]:
    """(rows, cols) of the conv5_3 map for an image of height x width (four ceil-mode pools)."""
    for _ in range(VGG16_LAYOUT.count("M")):
        height, width = -(-height // 2), -(-width // 2)
    return height, width


class VGG16Trunk(nn.Module):
    """conv1_1 .. conv5_3, ReLUs, four ceil-mode max-pools: (B,3,H,W) -> (B,C,ceil(H/16),ceil(W/16))."""

    def __init__(self, width: float = 1.0, batch_norm: bool = False) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        in_channels = 3
        for item in VGG16_LAYOUT:
            if item == "M":
                layers.append(nn.MaxPool2d(kernel_size=2, stride=2, ceil_mode=True))
            else:
                out_channels = scaled_channels(int(item), width)
                relu: nn.Module = nn.ReLU(inplace=True)
                if batch_norm:
                    relu = nn.Sequential(nn.BatchNorm2d(out_channels), relu)
                layers += [nn.Conv2d(in_channels, out_channels, 3, padding=1), relu]
                in_channels = out_channels
        self.features = nn.Sequential(*layers)
        self.out_channels = in_channels
        for _, conv in self.convs():  # torchvision's VGG init
            nn.init.kaiming_normal_(conv.weight, mode="fan_out", nonlinearity="relu")
            nn.init.zeros_(conv.bias)

    def convs(self) -> list[tuple[int, nn.Conv2d]]:
        """(torchvision features index, conv) for the 13 convs, conv1_1 first."""
        return [(i, m) for i, m in enumerate(self.features) if isinstance(m, nn.Conv2d)]

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.features(image)

    def fold_batch_norms(self) -> None:
        """Fold each BatchNorm's running statistics into its conv (in place; eval-mode semantics)."""
        for index, conv in self.convs():
            slot = self.features[index + 1]
            if isinstance(slot, nn.Sequential):
                self.features[index] = fuse_conv_bn_eval(conv.eval(), slot[0].eval())
                self.features[index + 1] = slot[1]
