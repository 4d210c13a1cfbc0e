"""Initial 3D boxes of 2D segment proposals (docs/conventions.md "Proposals and initial 3D boxes").

A proposal's z is the median raw depth over its pixels with valid (non-zero) raw depth, or, when
it has none, the median hole-filled depth over all its pixels. Its (x, y) is the back-projection
at that z of its centroid pixel (the mean (u, v) over all its pixels, README pixel convention:
x = (u - cx) z / fx, y = (v - cy) z / fy, camera frame x right, y down, z forward, metres).

Proposals arrive as unions of superpixels, so everything is computed per superpixel once and
summed per proposal over its member superpixels (CSR `indptr`, `indices`), without a loop over
proposals. Medians come from per-superpixel cumulative depth histograms (bins of
`LiftConfig.bin_width` metres): a vectorised bisection over the bins finds, for every proposal at
once, the bin holding the middle order statistic(s), and the value is interpolated inside that
bin as if its pixels were spread evenly. Each order statistic thus lies in the same bin as the
exact one, so the median differs from numpy's exact np.median by less than one bin width
(a few float32 ulps more where a depth value falls exactly on a bin edge).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from a3d.runtime.structures.boxes import BOX_DIM, CENTER, SIZE
from a3d.runtime.structures.geometry import CameraLike, backproject


class SuperpixelProposals(Protocol):
    """What lift needs of a proposal set: an (H, W) integer superpixel label map (ids 0..S-1) and,
    per proposal, its member superpixel ids in CSR form (`indptr` (N+1,), `indices`)."""

    superpixels: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray


@dataclass(frozen=True)
class LiftConfig:
    """`bin_width`: depth histogram bin (metres); the median's error bound."""

    bin_width: float = 0.01


@dataclass(frozen=True)
class LiftedProposals:
    """`centers` (N, 3) float64 camera-frame initial box centres (metres); `valid` (N,) False
    where the proposal has no pixel or no depth at all, raw or filled (centre 0 there, never
    NaN); `from_filled` (N,) True where z came from the hole-filled depth (no valid raw pixel)."""

    centers: np.ndarray
    valid: np.ndarray
    from_filled: np.ndarray


def lift(
    proposals: SuperpixelProposals | np.ndarray,
    depth_raw: np.ndarray,
    depth_filled: np.ndarray,
    K: CameraLike,
    config: LiftConfig = LiftConfig(),
) -> LiftedProposals:
    """Initial centres of N proposals: superpixel form, or an (N, H, W) boolean mask stack."""
    if isinstance(proposals, np.ndarray):
        labels, indptr, indices = masks_to_superpixels(proposals)
    else:
        labels, indptr, indices = proposals.superpixels, proposals.indptr, proposals.indices
    labels = np.asarray(labels)
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if labels.ndim != 2 or labels.shape != depth_raw.shape or labels.shape != depth_filled.shape:
        raise ValueError(
            f"lift: superpixels {labels.shape}, raw depth {depth_raw.shape} and filled depth "
            f"{depth_filled.shape} must be (H, W) maps of one size"
        )
    if labels.size == 0 or labels.min() < 0:
        raise ValueError("lift: superpixel labels must be non-negative integers")
    n_sp = int(labels.max()) + 1
    if indptr.ndim != 1 or indptr.size < 1 or indptr[0] != 0 or indptr[-1] != indices.size:
        raise ValueError("lift: proposal indptr must start at 0 and end at len(indices)")
    if indices.size and (indices.min() < 0 or indices.max() >= n_sp):
        raise ValueError(f"lift: proposal member ids must lie in [0, {n_sp}) (the superpixel labels)")

    h, w = labels.shape
    sp = labels.ravel()
    per_sp = np.stack(
        [
            np.bincount(sp, minlength=n_sp),
            np.bincount(sp, np.tile(np.arange(w, dtype=np.float64), h), n_sp),
            np.bincount(sp, np.repeat(np.arange(h, dtype=np.float64), w), n_sp),
        ],
        axis=1,
    )
    count, sum_u, sum_v = _segment_sum(per_sp.take(indices, axis=0), indptr).T

    z, n_raw = _segment_medians(sp, depth_raw.ravel(), indptr, indices, n_sp, config.bin_width)
    from_filled = (count > 0) & (n_raw == 0)
    if from_filled.any():
        sub_indptr, sub_indices = _sub_csr(indptr, indices, np.flatnonzero(from_filled))
        z[from_filled], _ = _segment_medians(
            sp, depth_filled.ravel(), sub_indptr, sub_indices, n_sp, config.bin_width
        )
    valid = (count > 0) & (z > 0)
    safe = np.maximum(count, 1)
    u_mean, v_mean = sum_u / safe, sum_v / safe
    z = np.where(valid, z, 0.0)
    centers = backproject(u_mean, v_mean, z, K)
    return LiftedProposals(centers, valid, from_filled & valid)


def initial_boxes(centers: np.ndarray, mean_sizes: np.ndarray) -> np.ndarray:
    """(N, 3) centres x (C, 3) class mean sizes [l, w, h] -> (N, C, 7) boxes [x, y, z, l, w, h, 0]."""
    centers = np.asarray(centers, dtype=np.float64)
    mean_sizes = np.asarray(mean_sizes, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3 or mean_sizes.ndim != 2 or mean_sizes.shape[1] != 3:
        raise ValueError(
            f"initial_boxes: want (N, 3) centres, (C, 3) sizes, got {centers.shape} and {mean_sizes.shape}"
        )
    n, c = len(centers), len(mean_sizes)
    boxes = np.zeros((n, c, BOX_DIM))
    boxes[:, :, CENTER] = centers[:, None, :]
    boxes[:, :, SIZE] = mean_sizes[None, :, :]
    return boxes


def masks_to_superpixels(masks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, H, W) boolean masks -> exact superpixel form (labels (H, W), indptr, indices).

    The superpixels are the pixel sets with one membership pattern across the N masks, so every
    mask is exactly the union of its members. Meant for tests and small N (cost O(N H W)).
    """
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise ValueError(f"lift: expected (N, H, W) boolean masks, got shape {masks.shape}")
    n, h, w = masks.shape
    if n == 0:
        return np.zeros((h, w), np.int32), np.zeros(1, np.int64), np.zeros(0, np.int64)
    packed = np.ascontiguousarray(np.packbits(masks.reshape(n, h * w), axis=0).T)  # (H*W, ceil(N/8))
    rows = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()  # one opaque key per pixel
    patterns, labels = np.unique(rows, return_inverse=True)
    patterns = patterns.view(np.uint8).reshape(len(patterns), packed.shape[1])
    member = np.unpackbits(patterns, axis=1, count=n).T.astype(bool)  # (N, S)
    proposal_of, indices = np.nonzero(member)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(proposal_of, minlength=n))])
    return labels.reshape(h, w).astype(np.int32), indptr, indices


def _segment_sum(values: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """Per-segment sums of `values` rows (segments given by CSR `indptr`; empty ones sum to 0)."""
    cum = np.zeros((len(values) + 1, *values.shape[1:]), dtype=values.dtype)
    np.cumsum(values, axis=0, out=cum[1:])
    return cum[indptr[1:]] - cum[indptr[:-1]]


def _sub_csr(indptr: np.ndarray, indices: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR rows `rows` of (indptr, indices) as a CSR of their own."""
    counts = indptr[rows + 1] - indptr[rows]
    sub_indptr = np.concatenate([[0], np.cumsum(counts)])
    starts = np.repeat(indptr[rows] - sub_indptr[:-1], counts)
    return sub_indptr, indices[starts + np.arange(sub_indptr[-1])]


def _segment_medians(
    sp: np.ndarray,
    values: np.ndarray,
    indptr: np.ndarray,
    indices: np.ndarray,
    n_sp: int,
    bin_width: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Median of the positive `values` (pixel i in superpixel sp[i]) over each CSR segment of
    superpixels, within one bin width of the exact median; (medians (N,), counts (N,)), 0 where
    the segment has no positive value."""
    n_seg = len(indptr) - 1
    # Only the superpixels that the segments use get histograms, under compact ids.
    used = np.zeros(n_sp, dtype=bool)
    used[indices] = True
    compact = (np.cumsum(used) - 1).astype(np.int32)
    n_used = int(compact[-1]) + 1
    values = values.astype(np.float32, copy=False)
    positive = values > 0
    if not positive.any():
        return np.zeros(n_seg), np.zeros(n_seg, dtype=np.int64)
    lo_d, hi_d, _, _ = cv2.minMaxLoc(values[None, :], positive[None, :].view(np.uint8))
    n_bins = int((hi_d - lo_d) / bin_width) + 1
    if n_used * n_bins >= 2**31:
        raise ValueError(f"lift: {n_used} superpixels x {n_bins} depth bins is too many; widen bin_width")
    scaled = (values - np.float32(lo_d)) * np.float32(1.0 / bin_width)
    bins = np.minimum(scaled.astype(np.int32), n_bins - 1)
    trash = n_used * n_bins  # the key of pixels without a value or outside every segment
    first_key = np.where(used, compact * np.int32(n_bins), np.int32(-1))[sp]
    # cum[k]: pixels with key < k, so superpixel s has cum[s * n_bins + b] - cum[s * n_bins] in bins < b;
    # counted at key + 1 and summed in place (a second array of this size costs more than the sum).
    key = np.where(positive & (first_key >= 0), first_key + bins + 1, np.int32(trash + 1))
    cum = np.bincount(key, minlength=trash + 2)
    np.cumsum(cum, out=cum)
    member_start = compact[indices].astype(np.int64) * n_bins
    base = _segment_sum(cum[member_start], indptr)
    counts = _segment_sum(cum[member_start + n_bins], indptr) - base

    # Order statistics k1 = (n - 1) // 2 and k2 = n // 2 (np.median averages them), both at once.
    rank = np.concatenate([(counts - 1) // 2, counts // 2])
    q_start = np.concatenate([member_start, member_start])  # member lists, once per statistic
    q_ptr = np.concatenate([indptr[:-1], indptr + len(member_start)])
    q_base = np.concatenate([base, base])
    lengths = np.diff(q_ptr)

    def below(b: np.ndarray) -> np.ndarray:  # per query: its segment's pixels in bins < b
        return _segment_sum(cum[q_start + np.repeat(b, lengths)], q_ptr) - q_base

    lo = np.zeros(len(rank), dtype=np.int64)
    hi = np.full(len(rank), n_bins - 1, dtype=np.int64)
    while (lo < hi).any():  # smallest bin b with below(b + 1) > rank
        mid = (lo + hi) // 2
        above = below(mid + 1) > rank
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid + 1)
    under = below(lo)
    in_bin = np.maximum(below(lo + 1) - under, 1)
    value = lo_d + bin_width * (lo + (rank - under + 0.5) / in_bin)
    median = 0.5 * (value[:n_seg] + value[n_seg:])
    return np.where(counts > 0, median, 0.0), counts
