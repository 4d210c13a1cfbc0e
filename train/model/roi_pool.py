"""RoI pooling in plain torch: bilinear RoIAlign as two matrix products per RoI, and max pooling.

Departure from the paper: Deng & Latecki use Fast R-CNN's max RoI pooling (integer-rounded
bins, max per bin). We use RoIAlign with torchvision's ``roi_align(aligned=True)`` semantics and
a fixed ``sampling_ratio``, because (docs/platform.md "RoI pooling without torchvision") it needs no
custom op, is differentiable, exports to ONNX with standard ops and is the fastest of the
measured forms in ONNX Runtime. Max RoI pooling has no torch op without torchvision;
``roi_max_pool`` writes it with masked maxima, for the ablation that measures this departure.

With a fixed number of samples per bin, bilinear sampling factorises by axis: for one RoI on a
map F (C, H, W), ``pooled[c] = Wy @ F[c] @ Wx.T`` where ``Wy`` (P, H) and ``Wx`` (P, W) hold the
bin-averaged hat-kernel weights of the sample rows and columns (coordinates clamped to the map,
samples beyond one cell outside the map weigh 0 — torchvision's rules). The batch index is
folded into the row weights, so all RoIs of all images are one GEMM plus one batched GEMM
(``separable_pool``; a3d-export writes a graph of the same sum on each RoI group's window,
a3d.export.roi_pool_onnx). The operation is linear in F, so it commutes with a 1x1 convolution
(see net.py's channel fusion).

Coordinates: RoIs are in the README's pixel coordinates (pixel (u, v) is centred at the point
(u, v); a box is its exact extent; the image spans [-0.5, W - 0.5]). torchvision's continuous
coordinates put pixel centres at u + 0.5, so a coordinate x maps to the feature-map coordinate
``(x + 0.5) * spatial_scale - 0.5`` (cell j's centre is at j). Memory: the intermediate is
R x P x C x W floats; chunk the RoIs when that is too large.
"""

from __future__ import annotations

import torch


def _axis_weights(
    start: torch.Tensor, end: torch.Tensor, length: int, output_size: int, sampling_ratio: int
) -> torch.Tensor:
    """(R, output_size, length) bilinear weights of one axis, averaged over each bin's samples.

    start, end: (R,) RoI extent in feature-map coordinates (cell j centred at j).
    """
    samples = output_size * sampling_ratio
    # Sample k of the RoI sits at fraction (k + 0.5) / samples: bin k // S, sample k % S within it.
    fraction = (torch.arange(samples, dtype=start.dtype, device=start.device) + 0.5) / samples
    position = start[:, None] + (end - start)[:, None] * fraction  # (R, samples)
    valid = (position >= -1.0) & (position <= length)
    position = position.clamp(0.0, length - 1.0)
    cells = torch.arange(length, dtype=start.dtype, device=start.device)
    hat = (1.0 - (position[:, :, None] - cells).abs()).clamp(min=0.0)  # (R, samples, length)
    hat = (hat * valid[:, :, None].to(hat.dtype)).reshape(-1, output_size, sampling_ratio, length)
    # the mean over each bin's samples as a sum of slices: exported, a mean over the middle axis
    # is ONNX Runtime's slow strided ReduceMean (1.1 ms of the paper's pooling at 500 RoIs)
    total = hat[:, :, 0]
    for sample in range(1, sampling_ratio):
        total = total + hat[:, :, sample]
    return total * (1.0 / sampling_ratio)


def roi_weights(
    features: torch.Tensor,
    rois: torch.Tensor,
    output_size: int = 7,
    spatial_scale: float = 1.0 / 16.0,
    sampling_ratio: int = 2,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Row weights (R, P, B*H) with the batch index folded in (RoI r weighs only its image's rows)
    and column weights (R, P, W), P = output_size, for ``separable_pool`` on ``pooling_rows(features)``."""
    batch, _, height, width = features.shape
    rois = rois.to(features.dtype)
    box = (rois[:, 1:5] + 0.5) * spatial_scale - 0.5
    wy = _axis_weights(box[:, 1], box[:, 3], height, output_size, sampling_ratio)  # (R, P, H)
    wx = _axis_weights(box[:, 0], box[:, 2], width, output_size, sampling_ratio)  # (R, P, W)
    images = torch.arange(batch, dtype=rois.dtype, device=rois.device)
    one_hot = (rois[:, 0:1] == images).to(features.dtype)  # (R, B)
    wy = (one_hot[:, None, :, None] * wy[:, :, None, :]).reshape(rois.shape[0], output_size, batch * height)
    return wy, wx


def pooling_rows(features: torch.Tensor) -> torch.Tensor:
    """The maps (B, C, H, W) as rows (B*H, C, W), the images stacked along y as the row weights index them."""
    batch, channels, height, width = features.shape
    return features.permute(0, 2, 1, 3).reshape(batch * height, channels, width)


def separable_pool(rows: torch.Tensor, wy: torch.Tensor, wx: torch.Tensor) -> torch.Tensor:
    """pooled[r, i, c, j] = sum_{h, w} wy[r, i, h] rows[h, c, w] wx[r, j, w]: (R, P, C, P), laid out
    (y, c, x), the order the two products leave it in (a3d.export folds it into fc6's weights).

    rows (B*H, C, W), wy (R, P, B*H), wx (R, P, W). All RoIs of all images are one GEMM plus one
    batched GEMM; the export writes a faster graph of the same sum (a3d.export.roi_pool_onnx).
    """
    count, size, stacked = wy.shape
    channels, width = rows.shape[1], rows.shape[2]
    pooled_rows = wy.reshape(count * size, stacked) @ rows.reshape(stacked, channels * width)  # (R*P, C*W)
    pooled = pooled_rows.reshape(count, size * channels, width) @ wx.transpose(1, 2)  # (R, P*C, P)
    return pooled.reshape(count, size, channels, size)


def roi_align(
    features: torch.Tensor,
    rois: torch.Tensor,
    output_size: int = 7,
    spatial_scale: float = 1.0 / 16.0,
    sampling_ratio: int = 2,
) -> torch.Tensor:
    """Pool each RoI to (C, output_size, output_size) from its image's feature map.

    features: (B, C, H, W). rois: (R, 5) rows [batch_index, x1, y1, x2, y2] in image pixel
    coordinates (README convention). spatial_scale: feature cells per image pixel (1/16 for
    conv5_3). Returns (R, C, output_size, output_size), flattening order (C, y, x) as
    torchvision's. Equals torchvision.ops.roi_align(features, rois + [0, .5, .5, .5, .5],
    output_size, spatial_scale, sampling_ratio, aligned=True).
    """
    wy, wx = roi_weights(features, rois, output_size, spatial_scale, sampling_ratio)
    return separable_pool(pooling_rows(features), wy, wx).permute(0, 2, 1, 3)


def roi_max_pool(
    features: torch.Tensor,
    rois: torch.Tensor,
    output_size: int = 7,
    spatial_scale: float = 1.0 / 16.0,
) -> torch.Tensor:
    """The paper's max RoI pooling (Fast R-CNN's ROIPoolingLayer), for training and the ablation.

    Same arguments and output layout as ``roi_align``. The RoI's first and last pixel
    (README coordinates: ``x1 + 0.5`` .. ``x2 - 0.5``) are scaled and rounded to map cells, the
    rounded RoI is split into output_size bins per axis with floor / ceil edges and each bin takes
    the maximum of its cells inside the map (0 for a bin wholly outside). Those bin edges are
    ``adaptive_max_pool2d``'s, so each RoI is its crop of the map (padded with -inf where it
    leaves the map) through that op: one small op per RoI. Not exportable: ``a3d-export``
    supports RoIAlign networks only.
    """
    _, channels, height, width = features.shape
    pixels = rois[:, 1:5].double() + torch.tensor([0.5, 0.5, -0.5, -0.5], dtype=torch.float64)
    scaled = pixels * spatial_scale  # first and last pixel, in map cells
    rounded = (torch.sign(scaled) * torch.floor(scaled.abs() + 0.5)).long()  # C's round(): half away from 0
    out = []
    for b, (x0, y0, x1, y1) in zip(rois[:, 0].tolist(), rounded.tolist(), strict=True):
        x1, y1 = max(x1, x0), max(y1, y0)  # a RoI is at least one cell
        crop = features[int(b), :, max(y0, 0) : min(y1 + 1, height), max(x0, 0) : min(x1 + 1, width)]
        pads = (max(-x0, 0), max(x1 + 1 - width, 0), max(-y0, 0), max(y1 + 1 - height, 0))
        if any(pads) or crop.numel() == 0:
            shape = (channels, y1 - y0 + 1, x1 - x0 + 1)
            full = features.new_full(shape, float("-inf"))
            ys, xs = max(-y0, 0), max(-x0, 0)
            full[:, ys : ys + crop.shape[1], xs : xs + crop.shape[2]] = crop
            crop = full
        out.append(torch.nn.functional.adaptive_max_pool2d(crop, output_size))
    if not out:
        return features.new_zeros((0, channels, output_size, output_size))
    pooled = torch.stack(out)
    return pooled.masked_fill(torch.isneginf(pooled), 0.0)
