"""Class-agnostic RGB-D segment proposals (the paper used MCG in MATLAB; this is a fast stand-in).

Pipeline, at 1/`scale` resolution (block means of the full-resolution images, so working pixel
(i, j) is exactly the full-resolution block [scale*i, scale*i+scale) x [scale*j, scale*j+scale)):

1. superpixels (a3d.runtime.frontend.superpixels): grid-seeded watershed on Lab colour, with depth
   discontinuities painted in as barriers;
2. hierarchical grouping (a3d.runtime.frontend.grouping): selective-search merging of the superpixels
   under twelve similarity strategies (colour histograms, colour / depth / normal boundary
   strength, normals, size, fill); every region formed is a candidate, so is every superpixel;
3. combinatorial grouping: disjoint pairs of well-ranked regions that are close in depth and
   colour and compact together (objects cut by an occluder or joined by a part too thin to
   segment) are candidates too;
4. ranking: an objectness score, the strength of the colour, depth and normal edges along the
   region's outline (1 - mean boundary similarity, weights 2, 1, 0.5), plus `jitter` times a
   uniform number from a fixed seed (as selective search randomises its ranking: variety among
   near-equal regions; deterministic); a pair scores the lower of its parts minus a penalty;
5. candidates below `min_area` full-resolution pixels go, identical member sets are kept once,
   near-duplicate boxes (IoU > `duplicate_iou`) keep the better-ranked one (greedy, best first),
   and the list is capped at `max_proposals`. A capped list is the head of a longer one.

Everything is returned in superpixel form at full resolution: one (H, W) int32 label map and,
per proposal, the superpixel ids it contains (CSR), with boxes in the README pixel convention
`[umin - 0.5, vmin - 0.5, umax + 0.5, vmax + 0.5]` computed from the members, so a box is
exactly the extent of its mask.

Measured with bench/frontend.py on 60 held-out a3d-synth frames (537 objects, 427 x 561):
recall of the visible boxes at IoU 0.5 of about 0.93 with 1000 proposals and 0.94 with 2000
(0.95 / 0.96 without the 2-3 % of objects smaller than `min_area`), at IoU 0.7 about 0.8;
about 50 ms per frame (docs/edge-speed.md "The proposal front end").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from a3d.runtime.clock import Clock
from a3d.runtime.frontend.grouping import (
    BoundaryScales,
    Hierarchies,
    LeafSpans,
    PairConfig,
    Strategy,
    build_graph,
    combine_pairs,
    group,
    outer_similarity,
    reduce_forest,
)
from a3d.runtime.frontend.normals import NormalConfig, surface_normals
from a3d.runtime.frontend.superpixels import SuperpixelConfig, depth_edges, oversegment
from a3d.runtime.io.plain_config import MAX_COUNT, dataclass_from_plain
from a3d.runtime.structures.geometry import Intrinsics, boxes_from_pixel_bounds

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
"""Colour, boundary-strength, geometry and shape-driven hierarchies. Diversity is what buys
recall: on held-out a3d-synth frames any one strategy reaches about 0.8 of the objects at IoU
0.5, all twelve about 0.95; batched in one pass they cost about twice a single one."""


@dataclass(frozen=True)
class ProposalConfig:
    """Proposal parameters.

    `max_proposals`: cap on the returned list; `min_area`: least mask area (full-resolution
    pixels); `scale`: working-resolution divisor (integer); `normals`: surface normals at the
    working resolution; `color_bins`: histogram bins per Lab channel; `edge_weights`: weights of
    the colour, depth and normal edge strength along a region's outline in its ranking score;
    `jitter` and `seed`: the random share of that score; `duplicate_iou`: boxes overlapping a
    better-ranked box by more than this (IoU) are dropped (1.0 keeps them all).
    """

    max_proposals: int = 2000
    min_area: int = 200
    scale: int = 2
    superpixels: SuperpixelConfig = field(default_factory=SuperpixelConfig)
    normals: NormalConfig = field(default_factory=lambda: NormalConfig(step=1, window=5))
    strategies: tuple[Strategy, ...] = DEFAULT_STRATEGIES
    boundary_scales: BoundaryScales = field(default_factory=BoundaryScales)
    pairs: PairConfig = field(default_factory=PairConfig)
    color_bins: int = 12
    edge_weights: tuple[float, float, float] = (2.0, 1.0, 0.5)
    jitter: float = 1.0
    seed: int = 0
    duplicate_iou: float = 0.95


_LIMITS = {  # settings narrower than plain_config's defaults (ints in [0, MAX_COUNT], floats >= 0)
    "max_proposals": (1, MAX_COUNT), "scale": (1, 64), "n_segments": (1, MAX_COUNT), "step": (1, 64),
    "window": (1, 255), "color_bins": (1, 256), "duplicate_iou": (0.0, 1.0), "min_valid_fraction": (0.0, 1.0),
}  # fmt: skip


LIVE_MAX_PROPOSALS = 500
LIVE_SCALE = 4
LIVE_SUPERPIXELS = 300
LIVE_STRATEGIES = 6
LIVE_PAIR_PARTS = 150


def live_proposals(config: ProposalConfig) -> ProposalConfig:
    """The live front end's cheaper version of a model's proposal settings: at most 500 proposals
    (the network's time grows with them), a quarter of the resolution, about 300 superpixels, the
    first six grouping strategies and pairs among the best 150 regions. On held-out 480 x 640
    a3d-synth frames it cuts the proposals from about 110 ms to about 24 ms for a few points of
    recall@0.5 and no mAP@0.25 (bench.live_rate, docs/live.md); the model's own settings stay the
    default for recorded frames."""
    return replace(
        config,
        max_proposals=min(config.max_proposals, LIVE_MAX_PROPOSALS),
        scale=LIVE_SCALE,
        superpixels=replace(config.superpixels, n_segments=LIVE_SUPERPIXELS),
        strategies=config.strategies[:LIVE_STRATEGIES],
        pairs=replace(config.pairs, parts=min(config.pairs.parts, LIVE_PAIR_PARTS)),
    )


def proposal_config_from_dict(values: Mapping[str, Any], where: str = "proposal_config") -> ProposalConfig:
    """A ProposalConfig from its plain form (nested dicts, lists for tuples; missing keys keep
    defaults), every value type- and range-checked: a ModelError names the first bad setting."""
    return dataclass_from_plain(ProposalConfig, values, where, _LIMITS)


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


PROPOSAL_STAGES = (
    "working_images", "superpixels", "region_graph", "grouping", "ranking", "pairs", "selection",
)  # fmt: skip
"""The stages of propose() that its ``timing`` receives, in order (bench.frontend prints them)."""


def propose(
    color: np.ndarray,
    depth_filled: np.ndarray,
    K: Intrinsics,
    config: ProposalConfig = ProposalConfig(),
    timing: dict[str, float] | None = None,
) -> Proposals:
    """Segment proposals for one frame.

    `color` (H, W, 3) uint8 BGR; `depth_filled` (H, W) float32 metres, hole-filled
    (a3d.runtime.frontend.depth.fill_depth; zeros are tolerated and treated as unknown depth);
    `K` the frame's intrinsics. `timing`, if given, receives the wall seconds of each of
    PROPOSAL_STAGES (added to what it holds).
    """
    _check_inputs(color, depth_filled, config)
    clock = Clock(timing)
    H, W = depth_filled.shape
    f = int(config.scale)
    lab = cv2.cvtColor(_block_mean(np.ascontiguousarray(color), f), cv2.COLOR_BGR2Lab)
    depth = _block_mean(np.asarray(depth_filled, np.float32), f)
    valid = depth > 0
    log_depth = np.where(valid, np.log(np.maximum(depth, 1e-6)), 0.0).astype(np.float32)
    # Working pixel i covers full pixels f*i .. f*i+f-1, centred at f*i + (f-1)/2.
    K_small = replace(K, fx=K.fx / f, fy=K.fy / f, cx=(K.cx - (f - 1) / 2) / f, cy=(K.cy - (f - 1) / 2) / f)
    normals = surface_normals(depth, K_small, config.normals)
    normal_ok = valid & ((normals[..., 0] != 0) | (normals[..., 1] != 0) | (normals[..., 2] != 0))
    clock.lap("working_images")

    labels = oversegment(
        lab, log_depth, depth_edges(log_depth, valid, config.superpixels), config.superpixels
    )
    clock.lap("superpixels")
    n_bins = int(config.color_bins)
    bins = (lab.astype(np.int32) * n_bins) >> 8
    bins += np.arange(3, dtype=np.int32) * n_bins
    gradients = _gradients(lab, log_depth, valid, normals, normal_ok)
    graph = build_graph(labels, bins, 3 * n_bins, gradients, log_depth, valid, normals, normal_ok)

    full = np.repeat(np.repeat(labels, f, axis=0), f, axis=1)[:H, :W]
    n_sp = graph.n
    sp_area = np.bincount(full.ravel(), minlength=n_sp).astype(np.int64)
    sp_box = np.concatenate(
        [graph.bbox[:, :2] * f, np.minimum(graph.bbox[:, 2:] * f + f - 1, [W - 1, H - 1])], 1
    )
    clock.lap("region_graph")

    # Hierarchies: superpixels first, then every region the strategies formed.
    hier = group(graph, config.strategies, config.boundary_scales, float(labels.size))
    clock.lap("grouping")
    # Candidates: the superpixels, then every region formed, then the pairs. A superpixel is its
    # leaf of the first strategy in the merge forest, a region its node, a pair its parts' nodes.
    spans = LeafSpans.of(hier)
    nodes = np.concatenate([np.arange(n_sp), hier.n_leaves + np.arange(hier.n)])
    stats = _candidate_stats(hier, sp_area, sp_box)
    outer = np.concatenate([outer_similarity(graph, config.boundary_scales), hier.outer])
    jitter = np.random.default_rng(config.seed).random(outer.shape[0])
    score = (1.0 - outer) @ np.asarray(config.edge_weights, float) + config.jitter * jitter

    # Pairs of the best distinct regions (down to a quarter of min_area: a piece may be small).
    parts = _ranked_unique(stats, np.nonzero(stats[:, _AREA] >= config.min_area / 4)[0], score)
    parts = parts[: config.pairs.parts]
    clock.lap("ranking")
    part_ptr, part_idx = spans.members(nodes[parts], np.arange(parts.size), parts.size, n_sp)
    centres = np.tile((np.arange(n_bins) + 0.5) * 256.0 / n_bins, 3)
    first, second, pair_score = combine_pairs(
        graph, part_ptr, part_idx, _boxes(stats[parts]), score[parts], centres, config.pairs
    )
    first, second = parts[first], parts[second]
    stats = np.concatenate([stats, _merge_stats(stats[first], stats[second])])
    score = np.concatenate([score, pair_score])
    clock.lap("pairs")

    keep = _ranked_unique(stats, np.nonzero(stats[:, _AREA] >= config.min_area)[0], score)
    keep = _best_distinct(_boxes(stats), keep, config.duplicate_iou, config.max_proposals)
    row = np.arange(keep.size)
    single, pair = keep < nodes.size, keep - nodes.size
    pair_row, pair = row[~single], pair[~single]
    indptr, indices = spans.members(
        np.concatenate([nodes[keep[single]], nodes[first[pair]], nodes[second[pair]]]),
        np.concatenate([row[single], pair_row, pair_row]),
        keep.size,
        n_sp,
    )
    proposals = Proposals(
        superpixels=np.ascontiguousarray(full, dtype=np.int32),
        indptr=indptr,
        indices=indices.astype(np.int32),
        boxes=_boxes(stats[keep]),
        scores=score[keep],
    )
    clock.lap("selection")
    return proposals


# Columns of a candidate's statistics (int64): superpixel count, full-resolution area, two random
# 64-bit member-set hashes (wrapping sums), inclusive pixel bounds [umin, vmin, umax, vmax].
_COUNT, _AREA, _HASH, _LOW, _HIGH = 0, 1, slice(2, 4), slice(4, 6), slice(6, 8)


def _candidate_stats(hier: Hierarchies, sp_area: np.ndarray, sp_box: np.ndarray) -> np.ndarray:
    """(S + M, 8) statistics of the superpixels and then of the regions of `hier`; the hashes
    are sums of two fixed random codes per superpixel, so equal member sets hash equal."""
    n_sp = sp_area.size
    codes = np.random.default_rng(12345).integers(0, np.iinfo(np.int64).max, size=(2, n_sp), dtype=np.int64).T
    leaves = np.concatenate([np.ones((n_sp, 1), np.int64), sp_area[:, None], codes, sp_box], axis=1)
    return np.concatenate([leaves, reduce_forest(hier, leaves, _merge_stats)])


def _merge_stats(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Statistics of the unions of disjoint candidates from theirs (rows of (N, 8))."""
    return np.concatenate(
        [a[:, :4] + b[:, :4], np.minimum(a[:, _LOW], b[:, _LOW]), np.maximum(a[:, _HIGH], b[:, _HIGH])],
        axis=1,
    )


def _boxes(stats: np.ndarray) -> np.ndarray:
    """(N, 4) README boxes of candidates: the exact extent of their masks."""
    return boxes_from_pixel_bounds(stats[:, 4:8])


def _check_inputs(color: np.ndarray, depth: np.ndarray, config: ProposalConfig) -> None:
    """One-line ValueErrors for inputs and settings propose() cannot work with."""
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise ValueError(f"proposals: colour must be (H, W, 3) uint8 BGR, got {color.shape} {color.dtype}")
    if depth.shape != color.shape[:2]:
        raise ValueError(f"proposals: depth is {depth.shape} but colour is {color.shape[:2]}")
    if depth.size == 0:
        raise ValueError(f"proposals: empty image {depth.shape}")
    if not np.isfinite(depth).all() or (depth < 0).any():
        raise ValueError("proposals: depth must be finite and >= 0 (0 = unknown)")
    if config.scale < 1 or config.max_proposals < 0 or not 0.0 < config.duplicate_iou <= 1.0:
        raise ValueError(
            f"proposals: bad config (scale {config.scale} >= 1, max_proposals {config.max_proposals} >= 0, "
            f"duplicate_iou {config.duplicate_iou} in (0, 1])"
        )


def _block_mean(image: np.ndarray, f: int) -> np.ndarray:
    """Mean over f x f blocks, same dtype (the last partial blocks are padded by replication)."""
    if f == 1:
        return image
    h, w = image.shape[:2]
    hs, ws = -(-h // f), -(-w // f)
    padded = cv2.copyMakeBorder(image, 0, hs * f - h, 0, ws * f - w, cv2.BORDER_REPLICATE)
    return cv2.resize(padded, (ws, hs), interpolation=cv2.INTER_AREA)


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


def _sum_segments(values: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """Per-CSR-row sums (rows are never empty)."""
    return np.add.reduceat(values, indptr[:-1]) if values.size else np.zeros(indptr.size - 1, values.dtype)


def _ranked_unique(stats: np.ndarray, rows: np.ndarray, score: np.ndarray) -> np.ndarray:
    """`rows` (ascending) without repeated member sets (the best-scored copy stays), best first
    (ties by row). Sets are compared by their two random 64-bit hashes (collisions of both are
    astronomically unlikely) and their size."""
    ranked = rows[np.argsort(-score[rows], kind="stable")]
    return ranked[first_of_equal(stats.take(ranked, axis=0)[:, [2, 3, _COUNT]])]


def first_of_equal(keys: np.ndarray) -> np.ndarray:
    """(N,) bool: True at the first of each set of equal rows of the (N, C) int64 `keys`.
    Grouped by the first column alone (one stable sort) unless that column puts unequal rows
    together, then by all columns."""
    order = np.argsort(keys[:, 0], kind="stable")
    in_order = keys.take(order, axis=0)
    same = in_order[1:] == in_order[:-1]
    if (same[:, 0] & ~same.all(axis=1)).any():
        order = np.lexsort(keys.T[::-1])
        in_order = keys.take(order, axis=0)
        same = in_order[1:] == in_order[:-1]
    first = np.ones(keys.shape[0], bool)
    first[order[1:]] = ~same.all(axis=1)
    return first


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
    box_i, box_j = boxes.take(i, axis=0), boxes.take(j, axis=0)
    lo = np.maximum(box_i[:, :2], box_j[:, :2])
    hi = np.minimum(box_i[:, 2:], box_j[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    close = inter > iou * (area[i] + area[j] - inter)
    better, worse = np.minimum(i[close], j[close]), np.maximum(i[close], j[close])
    state = np.zeros(n, np.int8)  # 0 undecided, 1 kept, -1 dropped
    has_better = np.zeros(n, bool)
    has_better[worse] = True
    state[~has_better] = 1
    while better.size:
        # A worse box is dropped once one close better box is kept ...
        hit = state[better] == 1
        state[worse[hit]] = -1
        # ... and kept once all its close better boxes are dropped.
        open_pair = state[worse] == 0
        better, worse = better[open_pair], worse[open_pair]
        pending = np.zeros(n, bool)
        pending[worse[state[better] != -1]] = True
        free = worse[~pending[worse]]
        state[free] = 1
        keep_pair = state[worse] == 0
        better, worse = better[keep_pair], worse[keep_pair]
    return rows[state >= 0]
