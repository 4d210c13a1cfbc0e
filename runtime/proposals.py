"""Class-agnostic RGB-D segment proposals (the paper used MCG in MATLAB; this is a fast stand-in).

Pipeline, at 1/`scale` resolution (block means of the full-resolution images, so working pixel
(i, j) is exactly the full-resolution block [scale*i, scale*i+scale) x [scale*j, scale*j+scale)):
1. superpixels: grid-seeded watershed on Lab colour with depth discontinuities and surface
   creases painted in as barriers (a3d.runtime.superpixels);
2. hierarchical grouping of the superpixels under several similarity strategies
   (a3d.runtime.grouping); every region formed is a candidate, and so is every superpixel;
3. candidates smaller than `min_area` full-resolution pixels go, identical member sets are kept
   once, candidates are ranked (below), near-duplicate boxes (IoU > `duplicate_iou`) keep the
   better-ranked one, and the list is capped at `max_proposals`.

Ranking follows selective search: within each strategy, a region's rank is its position counted
from the top of the hierarchy (the last merge is 1), multiplied by a uniform random number from
a fixed seed (so the ranking is deterministic); superpixels count as the bottom level. The
lowest value across strategies wins; the score is its negative.

Everything is returned in superpixel form at full resolution: one (H, W) int32 label map and,
per proposal, the superpixel ids it contains (CSR), with boxes in the README pixel convention
`[umin - 0.5, vmin - 0.5, umax + 0.5, vmax + 0.5]` computed from the members, so a box is
exactly the extent of its mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from a3d.runtime.geometry import Intrinsics
from a3d.runtime.grouping import BoundaryScales, Strategy, build_graph, group, outer_similarity
from a3d.runtime.normals import NormalConfig, surface_normals
from a3d.runtime.superpixels import SuperpixelConfig, geometric_edges, oversegment

DEFAULT_STRATEGIES: tuple[Strategy, ...] = (
    Strategy(color=1.0, size=1.0, fill=1.0),
    Strategy(boundary_color=1.0, boundary_depth=1.0, boundary_normal=1.0, size=1.0),
    Strategy(color=1.0, boundary_depth=1.0, normal=1.0, size=1.0, fill=1.0),
    Strategy(boundary_depth=1.0, boundary_normal=1.0, fill=1.0, size=1.0),
    Strategy(boundary_color=1.0, size=1.0),
    Strategy(boundary_color=1.0, boundary_depth=1.0, fill=1.0),
    Strategy(color=1.0, boundary_color=1.0, size=1.0),
    Strategy(color=1.0, boundary_depth=1.0, size=1.0),
    Strategy(normal=1.0, boundary_depth=1.0, size=1.0),
    Strategy(fill=1.0, size=1.0),
    Strategy(boundary_color=1.0, boundary_depth=1.0, boundary_normal=1.0),
    Strategy(boundary_color=1.0, boundary_depth=1.0),
)
"""Colour, boundary-strength, geometry and shape-driven hierarchies: diversity is what buys recall."""


@dataclass(frozen=True)
class ProposalConfig:
    """Proposal parameters. `scale`: working-resolution divisor (integer); `min_area`: least
    mask area in full-resolution pixels; `duplicate_iou`: boxes overlapping a better-ranked box
    by more than this are dropped; `color_bins`: histogram bins per Lab channel; `seed`: the
    ranking's random seed."""

    max_proposals: int = 2000
    min_area: int = 200
    scale: int = 2
    superpixels: SuperpixelConfig = SuperpixelConfig()
    strategies: tuple[Strategy, ...] = DEFAULT_STRATEGIES
    boundary_scales: BoundaryScales = BoundaryScales()
    normals: NormalConfig = field(default_factory=lambda: NormalConfig(step=1, window=5))
    color_bins: int = 12
    duplicate_iou: float = 0.95
    seed: int = 0


@dataclass(frozen=True)
class Proposals:
    """Segment proposals in superpixel form, best first.

    `superpixels` (H, W) int32 label map 0..S-1; proposal i is the union of the superpixels
    `indices[indptr[i]:indptr[i+1]]` (sorted); `boxes` (N, 4) float64 `[x1, y1, x2, y2]` the exact
    pixel extent of each mask (README convention); `scores` (N,) float64, non-increasing.
    """

    superpixels: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    def members(self, i: int) -> np.ndarray:
        """Superpixel ids of proposal i."""
        return self.indices[self.indptr[i] : self.indptr[i + 1]]

    def mask(self, i: int) -> np.ndarray:
        """(H, W) bool mask of proposal i."""
        lut = np.zeros(int(self.superpixels.max()) + 1, bool)
        lut[self.members(i)] = True
        return lut[self.superpixels]

    def areas(self) -> np.ndarray:
        """(N,) mask areas in pixels."""
        sp_area = np.bincount(self.superpixels.ravel()).astype(np.int64)
        return _sum_segments(sp_area[self.indices], self.indptr)


def propose(
    color: np.ndarray, depth_filled: np.ndarray, K: Intrinsics, config: ProposalConfig = ProposalConfig()
) -> Proposals:
    """Segment proposals for one frame.

    `color` (H, W, 3) uint8 BGR; `depth_filled` (H, W) float32 metres, hole-filled
    (a3d.runtime.depth.fill_depth; zeros are tolerated and treated as unknown depth);
    `K` the frame's intrinsics.
    """
    _check_inputs(color, depth_filled, config)
    H, W = depth_filled.shape
    f = int(config.scale)
    bgr = _block_mean(color.astype(np.float32), f)
    lab = cv2.cvtColor(np.clip(bgr + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_BGR2Lab)
    depth = _block_mean(np.asarray(depth_filled, np.float32), f)
    valid = depth > 0
    log_depth = np.where(valid, np.log(np.maximum(depth, 1e-6)), 0.0).astype(np.float32)
    K_small = replace(K, fx=K.fx / f, fy=K.fy / f, cx=(K.cx - (f - 1) / 2) / f, cy=(K.cy - (f - 1) / 2) / f)
    normals = surface_normals(depth, K_small, config.normals)
    normal_ok = valid & (np.abs(normals).sum(axis=2) > 0)

    barrier = geometric_edges(log_depth, valid, normals, normal_ok, config.superpixels)
    labels = oversegment(lab, log_depth, barrier, config.superpixels)
    gradients = _gradients(lab, log_depth, valid, normals, normal_ok)
    n_bins = int(config.color_bins)
    bins = (lab.astype(np.int32) * n_bins) >> 8
    bins += np.arange(3, dtype=np.int32) * n_bins
    graph = build_graph(labels, bins, 3 * n_bins, gradients, normals, normal_ok)

    full = np.repeat(np.repeat(labels, f, axis=0), f, axis=1)[:H, :W]
    n_sp = graph.n
    sp_area = np.bincount(full.ravel(), minlength=n_sp).astype(np.int64)
    sp_box = np.empty((n_sp, 4), np.int64)
    sp_box[:, :2] = graph.bbox[:, :2] * f
    sp_box[:, 2] = np.minimum(graph.bbox[:, 2] * f + f - 1, W - 1)
    sp_box[:, 3] = np.minimum(graph.bbox[:, 3] * f + f - 1, H - 1)

    indptr, indices, cand = _candidates(graph, config, float(labels.size))
    area = _sum_segments(sp_area[indices], indptr)
    score = _score(cand, area, H * W)
    priority = -score
    keep = np.nonzero(area >= config.min_area)[0]
    keep = _unique_members(indptr, indices, keep, priority, n_sp)
    boxes = _member_boxes(sp_box, indptr, indices)
    keep = keep[np.lexsort((keep, priority[keep]))]
    keep = _best_distinct(boxes, keep, config.duplicate_iou, config.max_proposals)

    out_indptr, out_indices = _select(indptr, indices, keep)
    return Proposals(
        superpixels=np.ascontiguousarray(full, dtype=np.int32),
        indptr=out_indptr,
        indices=out_indices.astype(np.int32),
        boxes=boxes[keep],
        scores=score[keep],
    )


def _check_inputs(color: np.ndarray, depth: np.ndarray, config: ProposalConfig) -> None:
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise ValueError(f"proposals: colour must be (H, W, 3) uint8 BGR, got {color.shape} {color.dtype}")
    if depth.shape != color.shape[:2]:
        raise ValueError(f"proposals: depth is {depth.shape} but colour is {color.shape[:2]}")
    if not np.isfinite(depth).all() or (depth < 0).any():
        raise ValueError("proposals: depth must be finite and >= 0 (0 = unknown)")
    if config.scale < 1 or config.max_proposals < 0:
        raise ValueError(f"proposals: bad config (scale {config.scale}, max_proposals {config.max_proposals})")


def _block_mean(image: np.ndarray, f: int) -> np.ndarray:
    """Mean over f x f blocks (the last partial blocks average the pixels they have)."""
    if f == 1:
        return image
    h, w = image.shape[:2]
    hs, ws = -(-h // f), -(-w // f)
    pad = ((0, hs * f - h), (0, ws * f - w)) + ((0, 0),) * (image.ndim - 2)
    padded = np.pad(image, pad, mode="edge")
    return padded.reshape(hs, f, ws, f, *image.shape[2:]).mean(axis=(1, 3), dtype=np.float32)


def _gradients(
    lab: np.ndarray, log_depth: np.ndarray, valid: np.ndarray, normals: np.ndarray, normal_ok: np.ndarray
) -> np.ndarray:
    """(h, w, 3) float32 per-pixel colour, depth and normal gradient strengths (Sobel / 8, L1)."""

    def strength(channel: np.ndarray) -> np.ndarray:
        gx = cv2.Sobel(channel, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(channel, cv2.CV_32F, 0, 1, ksize=3)
        return (np.abs(gx) + np.abs(gy)) / 8.0

    color = sum(strength(np.ascontiguousarray(lab[..., c], dtype=np.float32)) for c in range(3))
    depth = np.where(valid, strength(log_depth), 0.0)
    normal = np.where(normal_ok, sum(strength(np.ascontiguousarray(normals[..., c])) for c in range(3)), 0.0)
    return np.stack([color, depth, normal], axis=2).astype(np.float32)


def _candidates(graph, config: ProposalConfig, image_area: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """All candidate regions (superpixels, then every strategy's merges) as CSR over superpixels,
    with per-candidate attributes for ranking."""
    n = graph.n
    hier = group(graph, config.strategies, config.boundary_scales, image_area)
    indptr = np.concatenate([np.arange(n + 1, dtype=np.int64), hier.indptr[1:] + n])
    indices = np.concatenate([np.arange(n, dtype=np.int64), hier.indices])
    attributes = {
        "outer": np.concatenate([outer_similarity(graph, config.boundary_scales), hier.outer]),
        "strategy": np.concatenate([np.full(n, -1), hier.strategy]),
        "order": np.concatenate([np.full(n, hier.order.max(initial=0) + 1), hier.order]),
    }
    return indptr, indices, attributes


def _score(cand: dict, area: np.ndarray, image_area: float) -> np.ndarray:
    """Objectness: how strong the colour and depth edges along the region's outline are."""
    outer = cand["outer"]
    jitter = np.random.default_rng(0).random(outer.shape[0])
    return 2.0 * (1.0 - outer[:, 0]) + (1.0 - outer[:, 1]) + 0.5 * jitter


def _sum_segments(values: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """Per-CSR-row sums (rows are never empty)."""
    return np.add.reduceat(values, indptr[:-1]) if values.size else np.zeros(indptr.size - 1, values.dtype)


def _member_boxes(sp_box: np.ndarray, indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(N, 4) README boxes from the inclusive pixel boxes of each row's superpixels."""
    starts = indptr[:-1]
    b = sp_box[indices]
    lo = np.minimum.reduceat(b[:, :2], starts, axis=0)
    hi = np.maximum.reduceat(b[:, 2:], starts, axis=0)
    return np.concatenate([lo - 0.5, hi + 0.5], axis=1).astype(np.float64)


def _unique_members(
    indptr: np.ndarray, indices: np.ndarray, rows: np.ndarray, priority: np.ndarray, n_sp: int
) -> np.ndarray:
    """`rows` with identical member sets reduced to the one of lowest priority value.

    Sets are compared by two independent random 64-bit sums of their members (collisions of
    both are astronomically unlikely) plus their size."""
    rng = np.random.default_rng(12345)
    codes = rng.integers(0, np.iinfo(np.int64).max, size=(2, n_sp), dtype=np.int64).astype(np.uint64)
    starts = indptr[:-1]
    h1 = np.add.reduceat(codes[0][indices], starts)[rows]
    h2 = np.add.reduceat(codes[1][indices], starts)[rows]
    count = np.diff(indptr)[rows].astype(np.uint64)
    order = np.lexsort((rows, priority[rows], count, h2, h1))
    key = np.stack([h1, h2, count], axis=1)[order]
    first = np.ones(order.size, bool)
    first[1:] = (key[1:] != key[:-1]).any(axis=1)
    return np.sort(rows[order[first]])


def _best_distinct(boxes: np.ndarray, ranked: np.ndarray, iou: float, limit: int) -> np.ndarray:
    """The first `limit` rows of `ranked` (best first) that survive near-duplicate suppression.
    Greedy suppression of a prefix only depends on that prefix, so it runs on growing prefixes
    until enough survive (the pair search is superlinear in the count)."""
    length = min(ranked.size, 2 * limit)
    while True:
        kept = _drop_near_duplicates(boxes[ranked[:length]], iou, ranked[:length])
        if kept.size >= limit or length == ranked.size:
            return kept[:limit]
        length = min(ranked.size, 2 * length)


def _drop_near_duplicates(boxes: np.ndarray, iou: float, rows: np.ndarray) -> np.ndarray:
    """Greedy suppression, in the given (best-first) order, of boxes whose IoU with a kept
    better box exceeds `iou`; returns the surviving `rows`.

    Candidate pairs: IoU > t needs an area ratio above t (so log areas within log(1/t): the same
    or the next bucket of that width) and |x1a - x1b| <= (1 - t) / t * min(wa, wb) (from
    IoU <= iw / uw and uw - iw = |dx1| + |dx2|), so each box searches an x1 band of its own bucket
    and of the next one in a list sorted by (bucket, x1). The greedy pass is then resolved in
    vectorised sweeps: a box whose close better boxes are all decided is dropped if one is kept."""
    n = boxes.shape[0]
    if n < 2 or iou >= 1.0:
        return rows
    width = boxes[:, 2] - boxes[:, 0]
    area = width * (boxes[:, 3] - boxes[:, 1])
    bucket = np.floor(np.log(area) / -np.log(iou))
    bucket -= bucket.min()
    reach = (1.0 - iou) / iou * width + 1e-9
    span = float(boxes[:, 0].max() - boxes[:, 0].min() + 2.0 * reach.max() + 1.0)
    key = bucket * span + boxes[:, 0]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    band = reach[order]
    same_end = np.searchsorted(sorted_key, sorted_key + band, side="right")
    next_lo = np.searchsorted(sorted_key, sorted_key + span - band, side="left")
    next_hi = np.searchsorted(sorted_key, sorted_key + span + band, side="right")
    start = np.concatenate([np.arange(n) + 1, next_lo])
    stop = np.concatenate([same_end, next_hi])
    counts = np.maximum(stop - start, 0)
    first = np.repeat(np.concatenate([np.arange(n), np.arange(n)]), counts)
    second = np.arange(counts.sum()) + np.repeat(start - (np.cumsum(counts) - counts), counts)
    i, j = order[first], order[second]
    lo = np.maximum(boxes[i, :2], boxes[j, :2])
    hi = np.minimum(boxes[i, 2:], boxes[j, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    close = inter > iou * (area[i] + area[j] - inter)
    better, worse = np.minimum(i[close], j[close]), np.maximum(i[close], j[close])
    state = np.zeros(n, np.int8)  # 0 undecided, 1 kept, -1 dropped
    state[np.setdiff1d(np.arange(n), worse)] = 1
    while better.size:
        # A worse box is dropped once one close better box is kept ...
        hit = state[better] == 1
        state[worse[hit]] = -1
        # ... and kept once all its close better boxes are dropped.
        open_pair = state[worse] == 0
        better, worse = better[open_pair], worse[open_pair]
        pending = np.zeros(n, bool)
        pending[worse[state[better] != -1]] = True
        free = np.setdiff1d(worse, np.nonzero(pending)[0])
        state[free] = 1
        keep_pair = state[worse] == 0
        better, worse = better[keep_pair], worse[keep_pair]
    return rows[state >= 0]


def _select(indptr: np.ndarray, indices: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR rows `rows`, in that order."""
    counts = np.diff(indptr)[rows]
    out_ptr = np.zeros(rows.size + 1, np.int64)
    out_ptr[1:] = np.cumsum(counts)
    starts = np.repeat(indptr[rows] - out_ptr[:-1], counts)
    return out_ptr, indices[np.arange(out_ptr[-1]) + starts]
