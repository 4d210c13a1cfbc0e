"""The multi-task loss (paper eq. 4, docs/conventions.md "Training").

    L = CE(p, c) + lambda_3d [c >= 1] smoothL1(t3d_c - v3d) + lambda_2d [c >= 1] smoothL1(t2d_c - v2d)

Cross-entropy is averaged over all RoIs of the mini-batch. The regression terms use the deltas of
the RoI's true class only, on the normalised targets, summed over the coordinates of the
foreground RoIs and divided by the number of RoIs (Fast R-CNN / Caffe SmoothL1Loss with sigma 1),
so lambda balances the terms exactly as in the release.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F


@dataclass
class LossTerms:
    """The total loss (for backward) and its parts (for logging)."""

    total: torch.Tensor
    cls: torch.Tensor
    box3d: torch.Tensor
    box2d: torch.Tensor
    accuracy: torch.Tensor  # fraction of RoIs classified right (no gradient)

    def as_floats(self) -> dict[str, float]:
        parts = {"loss": self.total, "loss_cls": self.cls, "loss_3d": self.box3d, "loss_2d": self.box2d,
                 "accuracy": self.accuracy}  # fmt: skip
        return {k: float(v.detach()) for k, v in parts.items()}


def class_deltas(deltas: torch.Tensor, labels: torch.Tensor, size: int) -> torch.Tensor:
    """(R, C*size) per-class deltas -> (R, size) deltas of each RoI's class ``labels`` (R,)."""
    per_class = deltas.view(deltas.shape[0], -1, size)
    return per_class[torch.arange(len(labels), device=labels.device), labels]


def detection_loss(
    class_logits: torch.Tensor,
    deltas3d: torch.Tensor,
    deltas2d: torch.Tensor,
    labels: torch.Tensor,
    targets3d: torch.Tensor,
    targets2d: torch.Tensor,
    weights3d: torch.Tensor,
    lambda_3d: float = 1.0,
    lambda_2d: float = 1.0,
) -> LossTerms:
    """Loss of one mini-batch.

    ``labels`` (R,) int64 softmax index (0 background); ``targets3d`` (R, 7) and ``targets2d``
    (R, 4) normalised targets of each RoI's class (ignored for background); ``weights3d`` (R,)
    1 where the 3D target is defined (a foreground RoI whose segment could be lifted), else 0.
    The 2D term applies to every foreground RoI.
    """
    num = max(len(labels), 1)
    cls = F.cross_entropy(class_logits, labels)
    fg = (labels > 0).to(class_logits.dtype)
    reg3d = F.smooth_l1_loss(class_deltas(deltas3d, labels, 7), targets3d, reduction="none", beta=1.0)
    reg2d = F.smooth_l1_loss(class_deltas(deltas2d, labels, 4), targets2d, reduction="none", beta=1.0)
    box3d = (reg3d.sum(dim=1) * weights3d * fg).sum() / num
    box2d = (reg2d.sum(dim=1) * fg).sum() / num
    total = cls + lambda_3d * box3d + lambda_2d * box2d
    with torch.no_grad():
        accuracy = (class_logits.argmax(dim=1) == labels).to(torch.float32).mean()
    return LossTerms(total, cls, box3d, box2d, accuracy)
