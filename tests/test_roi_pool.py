"""RoI pooling (a3d.train.model.roi_pool) against independent per-RoI references: torchvision's
RoIAlign per sample, Fast R-CNN's max RoI pooling per bin."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from a3d.train.model.roi_pool import roi_align, roi_max_pool


def _bilinear(fmap: np.ndarray, y: float, x: float) -> np.ndarray:
    """torchvision's CPU roi_align bilinear_interpolate, transcribed branch by branch."""
    height, width = fmap.shape[1:]
    if y < -1.0 or y > height or x < -1.0 or x > width:
        return np.zeros(fmap.shape[0])
    y, x = max(y, 0.0), max(x, 0.0)
    y_low, x_low = int(y), int(x)
    if y_low >= height - 1:
        y_high = y_low = height - 1
        y = float(y_low)
    else:
        y_high = y_low + 1
    if x_low >= width - 1:
        x_high = x_low = width - 1
        x = float(x_low)
    else:
        x_high = x_low + 1
    ly, lx = y - y_low, x - x_low
    hy, hx = 1.0 - ly, 1.0 - lx
    return (
        hy * hx * fmap[:, y_low, x_low]
        + hy * lx * fmap[:, y_low, x_high]
        + ly * hx * fmap[:, y_high, x_low]
        + ly * lx * fmap[:, y_high, x_high]
    )


def reference_roi_align(features, rois_torchvision, output_size, scale, sampling_ratio):
    """torchvision.ops.roi_align(aligned=True) with loops; boxes in torchvision's convention."""
    features = np.asarray(features, dtype=np.float64)
    out = np.zeros((len(rois_torchvision), features.shape[1], output_size, output_size))
    for r, (b, x1, y1, x2, y2) in enumerate(np.asarray(rois_torchvision, dtype=np.float64)):
        start_x, start_y = x1 * scale - 0.5, y1 * scale - 0.5
        bin_w = (x2 * scale - 0.5 - start_x) / output_size
        bin_h = (y2 * scale - 0.5 - start_y) / output_size
        for ph in range(output_size):
            for pw in range(output_size):
                total = np.zeros(features.shape[1])
                for iy in range(sampling_ratio):
                    y = start_y + ph * bin_h + (iy + 0.5) * bin_h / sampling_ratio
                    for ix in range(sampling_ratio):
                        x = start_x + pw * bin_w + (ix + 0.5) * bin_w / sampling_ratio
                        total += _bilinear(features[int(b)], y, x)
                out[r, :, ph, pw] = total / sampling_ratio**2
    return out


# Boxes in the README's pixel coordinates on a 80 x 112 image (stride 16 -> 5 x 7 map):
# inside, partly and wholly outside the image, tiny, degenerate, whole image, other image.
ROIS = [
    [0, 10.0, 12.0, 60.0, 70.0],
    [1, -30.0, -20.0, 40.0, 35.0],
    [0, 90.0, 50.0, 150.0, 120.0],
    [1, -0.5, -0.5, 111.5, 79.5],
    [0, 33.2, 41.7, 34.1, 42.0],
    [1, 50.0, 20.0, 50.0, 20.0],
    [0, 200.0, 200.0, 260.0, 230.0],
    [1, 7.9, 70.3, 103.6, 79.4],
]


@pytest.mark.parametrize(("output_size", "sampling_ratio"), [(7, 2), (3, 1), (2, 3)])
def test_matches_the_per_sample_reference(output_size: int, sampling_ratio: int) -> None:
    gen = torch.Generator().manual_seed(0)
    features = torch.randn(2, 3, 5, 7, generator=gen)
    rois = torch.tensor(ROIS)
    got = roi_align(features, rois, output_size, 1 / 16, sampling_ratio)
    shifted = rois.numpy() + np.array([0.0, 0.5, 0.5, 0.5, 0.5])  # README -> torchvision pixel centres
    want = reference_roi_align(features.numpy(), shifted, output_size, 1 / 16, sampling_ratio)
    assert got.shape == (len(ROIS), 3, output_size, output_size)
    np.testing.assert_allclose(got.numpy(), want, atol=1e-5)
    assert np.abs(want[6]).max() == 0.0  # a box far outside the image pools to zero


def test_pixel_convention_on_a_linear_ramp() -> None:
    """On F[y, x] = x (cell j centred at image pixel 16 j + 7.5), a bin pools its centre's x."""
    features = torch.arange(10.0).repeat(1, 1, 6, 1)  # (1, 1, 6, 10): value = column index
    x1, x2 = 20.0, 104.0  # inside the map's clamp-free range [7.5, 151.5]
    rois = torch.tensor([[0, x1, 30.0, x2, 60.0]])
    got = roi_align(features, rois, output_size=7, spatial_scale=1 / 16, sampling_ratio=2)[0, 0]
    bin_centres = x1 + (np.arange(7) + 0.5) * (x2 - x1) / 7
    want_cells = (bin_centres - 7.5) / 16  # image pixel u lies at feature column (u + 0.5) / 16 - 0.5
    np.testing.assert_allclose(got.numpy(), np.tile(want_cells, (7, 1)), atol=1e-5)


def test_each_roi_reads_only_its_own_image() -> None:
    gen = torch.Generator().manual_seed(1)
    features = torch.randn(2, 4, 5, 7, generator=gen)
    rois = torch.tensor(ROIS)
    before = roi_align(features, rois)
    features[0] += 100.0
    after = roi_align(features, rois)
    on_image_1 = rois[:, 0] == 1
    assert torch.equal(before[on_image_1], after[on_image_1])
    assert not torch.allclose(before[~on_image_1][:2], after[~on_image_1][:2])


def test_commutes_with_a_1x1_convolution() -> None:
    """The basis of channel fusion before pooling (net.py): pool(conv1x1(F)) == conv1x1(pool(F))."""
    gen = torch.Generator().manual_seed(2)
    features = torch.randn(2, 6, 5, 7, generator=gen, dtype=torch.float64)
    weight = torch.randn(4, 6, 1, 1, generator=gen, dtype=torch.float64)
    rois = torch.tensor(ROIS, dtype=torch.float64)
    fused_first = roi_align(torch.nn.functional.conv2d(features, weight), rois)
    pooled_first = torch.nn.functional.conv2d(roi_align(features, rois), weight)
    torch.testing.assert_close(fused_first, pooled_first, rtol=1e-10, atol=1e-10)


def test_gradient_matches_finite_differences() -> None:
    gen = torch.Generator().manual_seed(3)
    features = torch.randn(2, 2, 3, 4, generator=gen, dtype=torch.float64, requires_grad=True)
    rois = torch.tensor([[0, 3.0, -9.0, 40.0, 30.0], [1, 10.3, 5.1, 12.9, 20.7]], dtype=torch.float64)

    def pool(f: torch.Tensor) -> torch.Tensor:
        return roi_align(f, rois, output_size=3, sampling_ratio=2)

    assert torch.autograd.gradcheck(pool, (features,), eps=1e-6, atol=1e-7)
    # The gradient of the pooled sum over one in-image RoI sums to the RoI's valid sample weight: 1 per bin.
    inside = torch.tensor([[0, 8.0, 8.0, 40.0, 30.0]], dtype=torch.float64)
    roi_align(features, inside, output_size=3).sum().backward()
    assert math.isclose(features.grad[0].sum().item(), 2 * 9, rel_tol=1e-12)  # 2 channels x 9 bins
    assert features.grad[1].abs().max().item() == 0.0


def round_half_away(v: float) -> float:
    """C's round(): halves away from zero."""
    return math.copysign(math.floor(abs(v) + 0.5), v)


def reference_roi_max_pool(
    features: np.ndarray, rois: np.ndarray, output_size: int, scale: float
) -> np.ndarray:
    """Fast R-CNN's Caffe ROIPoolingLayer::Forward_cpu, transcribed loop by loop; rois in Caffe's
    0-based pixel indices (first and last pixel of the box)."""
    _, channels, height, width = features.shape
    out = np.zeros((len(rois), channels, output_size, output_size))
    for r, (b, x1, y1, x2, y2) in enumerate(rois):
        sw, sh, ew, eh = (int(round_half_away(v * scale)) for v in (x1, y1, x2, y2))
        bin_h, bin_w = max(eh - sh + 1, 1) / output_size, max(ew - sw + 1, 1) / output_size
        for ph in range(output_size):
            for pw in range(output_size):
                hs = min(max(math.floor(ph * bin_h) + sh, 0), height)
                he = min(max(math.ceil((ph + 1) * bin_h) + sh, 0), height)
                ws = min(max(math.floor(pw * bin_w) + sw, 0), width)
                we = min(max(math.ceil((pw + 1) * bin_w) + sw, 0), width)
                if he > hs and we > ws:
                    out[r, :, ph, pw] = features[int(b), :, hs:he, ws:we].max(axis=(1, 2))
    return out


@pytest.mark.parametrize("output_size", [7, 3, 2])
def test_max_pool_matches_fast_rcnn(output_size: int) -> None:
    gen = torch.Generator().manual_seed(4)
    features = torch.randn(2, 3, 5, 7, generator=gen)
    rois = torch.tensor(ROIS)
    got = roi_max_pool(features, rois, output_size, 1 / 16)
    caffe = rois.numpy() + np.array([0.0, 0.5, 0.5, -0.5, -0.5])  # README extent -> first/last pixel
    want = reference_roi_max_pool(features.numpy().astype(np.float64), caffe, output_size, 1 / 16)
    assert got.shape == (len(ROIS), 3, output_size, output_size)
    np.testing.assert_allclose(got.numpy(), want, atol=1e-6)
    assert np.abs(want[6]).max() == 0.0  # a box far outside the image pools to zero


def test_max_pool_gradient_goes_to_each_bins_maximum() -> None:
    features = torch.randn(1, 2, 4, 4, generator=torch.Generator().manual_seed(5), requires_grad=True)
    rois = torch.tensor([[0, -0.5, -0.5, 55.5, 55.5]])  # pixels 0 .. 55 round to cells 0 .. 3: the whole map
    pooled = roi_max_pool(features, rois, output_size=4)
    torch.testing.assert_close(pooled[0], features[0])
    roi_max_pool(features, rois, output_size=2).sum().backward()  # 2 x 2 cells per bin
    grad = features.grad[0]
    assert grad.sum().item() == 2 * 4 and set(grad.unique().tolist()) == {0.0, 1.0}
    blocks = features[0].detach().reshape(2, 2, 2, 2, 2).permute(0, 1, 3, 2, 4).reshape(2, 2, 2, 4)
    winners = grad.reshape(2, 2, 2, 2, 2).permute(0, 1, 3, 2, 4).reshape(2, 2, 2, 4).argmax(-1)
    assert torch.equal(winners, blocks.argmax(-1))
