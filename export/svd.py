"""Truncated SVD of the fully connected layers fc6 and fc7 (Fast R-CNN, Girshick 2015, sec. 3.1).

A Linear layer y = W x + b with W (out, in) is replaced by two: y = U_r (S_r V_r^T x) + b, i.e.
Linear(in, r, no bias) then Linear(r, out) with the original bias, which costs r (in + out)
multiply-adds per RoI instead of in * out (a saving for r < in * out / (in + out)). The singular
values are split evenly between the two factors (sqrt(S_r) on each side), which keeps both
weight matrices in a similar range for int8 quantisation; the product is the same as Fast
R-CNN's S_r V_r^T / U_r split. At full rank r = min(in, out) the layer is reproduced to float
rounding; a larger rank is capped there.

The factorisation is done on the torch model before export, so the export is verified against
the compressed torch model, and compared to the uncompressed one separately (a3d.export.cli).
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from a3d.train.model.net import A3DNet

SVD_LAYERS = ("fc6", "fc7")


def truncated_svd(layer: nn.Linear, rank: int) -> tuple[nn.Sequential, dict]:
    """Two Linears equal to ``layer`` at ``rank`` (at most its full rank min(out, in)), and a
    summary: shape, rank used, weights before and after, fraction of the squared singular values kept."""
    if rank < 1:
        raise ValueError(f"--svd {rank}: the rank must be a positive integer")
    weight = layer.weight.detach().double()
    rank = min(rank, *weight.shape)
    u, s, vh = torch.linalg.svd(weight, full_matrices=False)
    root = s[:rank].sqrt()
    first = nn.Linear(weight.shape[1], rank, bias=False)
    second = nn.Linear(rank, weight.shape[0], bias=layer.bias is not None)
    dtype = layer.weight.dtype
    with torch.no_grad():
        first.weight.copy_((root[:, None] * vh[:rank]).to(dtype))
        second.weight.copy_((u[:, :rank] * root[None, :]).to(dtype))
        if layer.bias is not None:
            second.bias.copy_(layer.bias)
    summary = {
        "shape": list(weight.shape),
        "rank": rank,
        "parameters": weight.numel(),
        "parameters_svd": rank * sum(weight.shape),
        "energy_kept": float((s[:rank] ** 2).sum() / (s**2).sum().clamp(min=1e-300)),
    }
    return nn.Sequential(first, second), summary


def svd_compress(net: A3DNet, rank: int) -> tuple[A3DNet, dict[str, dict]]:
    """An eval-mode copy of ``net`` with fc6 and fc7 factorised at ``rank`` (capped at each layer's
    full rank, where the factorisation is exact), and per-layer summaries."""
    out = copy.deepcopy(net).eval()
    summaries = {}
    for name in SVD_LAYERS:
        factored, summaries[name] = truncated_svd(getattr(net, name), rank)
        setattr(out, name, factored)
    return out, summaries
