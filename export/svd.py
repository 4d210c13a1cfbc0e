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
    wide = weight.shape[1] > weight.shape[0]
    # The leading singular vectors from the Gram matrix on the smaller side (W W^T = U S^2 U^T or
    # W^T W = V S^2 V^T): LAPACK's SVD of the paper's fc6 (4096 x 50176, float64) takes most of an
    # hour on 2 cores, this about a minute. Either way the pair computes U_r U_r^T W or W V_r V_r^T,
    # the projection on the leading singular subspace, i.e. the truncated SVD (Eckart-Young), and
    # W itself at full rank whatever its conditioning.
    values, vectors = torch.linalg.eigh(weight @ weight.T if wide else weight.T @ weight)  # ascending
    basis = vectors.flip(1)[:, :rank]  # U_r (wide) or V_r
    squares = values.flip(0)[:rank].clamp(min=0)  # S_r^2
    root = squares.sqrt().sqrt()  # sqrt(S_r); 1 where S_r is at the Gram matrix's rounding level
    root = torch.where(root > 1e-4 * root.max(), root, torch.ones_like(root))
    first = nn.Linear(weight.shape[1], rank, bias=False)
    second = nn.Linear(rank, weight.shape[0], bias=layer.bias is not None)
    if wide:
        first_weight, second_weight = (basis.T @ weight) / root[:, None], basis * root
    else:
        first_weight, second_weight = root[:, None] * basis.T, (weight @ basis) / root
    dtype = layer.weight.dtype
    with torch.no_grad():
        first.weight.copy_(first_weight.to(dtype))  # sqrt(S_r) V_r^T
        second.weight.copy_(second_weight.to(dtype))  # U_r sqrt(S_r)
        if layer.bias is not None:
            second.bias.copy_(layer.bias)
    summary = {
        "shape": list(weight.shape),
        "rank": rank,
        "parameters": weight.numel(),
        "parameters_svd": rank * sum(weight.shape),
        "energy_kept": float(squares.sum() / weight.square().sum().clamp(min=1e-300)),
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
