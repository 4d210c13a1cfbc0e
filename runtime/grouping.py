"""Hierarchical grouping of superpixels into segment proposals (selective-search style, RGB-D).

Why this design: selective search (Uijlings et al. 2013) merges the most similar pair of adjacent
regions until one is left and takes every region it ever formed as a proposal; several
similarity mixes ("strategies") diversify the set. A sequential merge loop in Python is too slow
for an edge runtime, so each strategy merges in *rounds*: every region whose most similar
neighbour also has it as its most similar neighbour merges with it (a matching of mutual best
pairs, which always contains the globally best pair), all pairs of a round at once, vectorised
over the region adjacency graph. Region statistics are additive (sizes, histogram counts,
sums, boundary sums), so a merge is a sum and the adjacency update is a re-keying plus
`np.bincount`.

Similarity terms, each in [0, 1] (1 = merge first):
colour (histogram intersection of Lab histograms), colour/depth/normal boundary (exp of minus
the mean gradient strength along the shared boundary over a scale), normal (cosine of the mean
normals), size (1 - joint size / image size) and fill (1 - bounding-box slack / image size).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class Strategy:
    """Weights of the similarity terms for one hierarchy (all >= 0, not all 0)."""

    color: float = 0.0
    boundary_color: float = 0.0
    boundary_depth: float = 0.0
    boundary_normal: float = 0.0
    normal: float = 0.0
    size: float = 0.0
    fill: float = 0.0


@dataclass(frozen=True)
class BoundaryScales:
    """Gradient strengths (per working pixel) at which a boundary similarity falls to 1/e:
    colour in Lab units (Sobel |gx|+|gy| / 8, summed over L, a, b), depth in log-depth units,
    normal as a unit-normal chord length."""

    color: float = 8.0
    depth: float = 0.02
    normal: float = 0.15


@dataclass
class RegionGraph:
    """Additive per-region statistics and the region adjacency graph (working resolution).

    Regions 0..N-1 are the superpixels. `bbox` is [umin, vmin, umax, vmax] (inclusive pixels);
    `color_hist` holds counts; `normal_sum` sums unit normals over valid-depth pixels.
    Edges `pairs` (E, 2) with a < b; `length` counts the 4-neighbour pixel pairs across the shared
    boundary, `strength` (E, 3) sums their colour, depth and normal gradient strengths.
    """

    size: np.ndarray
    bbox: np.ndarray
    color_hist: np.ndarray
    normal_sum: np.ndarray
    pairs: np.ndarray
    length: np.ndarray
    strength: np.ndarray

    @property
    def n(self) -> int:
        return int(self.size.shape[0])


@dataclass
class Hierarchy:
    """The regions one strategy formed by merging, in order of creation.

    Region k of the hierarchy has superpixels `indices[indptr[k]:indptr[k+1]]`; `similarity`
    is the similarity of the pair whose merge made it, `level` the merge round.
    """

    indptr: np.ndarray
    indices: np.ndarray
    similarity: np.ndarray
    level: np.ndarray


def build_graph(
    labels: np.ndarray,
    color_bins: np.ndarray,
    n_bins: int,
    gradients: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
) -> RegionGraph:
    """Statistics of the superpixels `labels` (h, w) int32 0..N-1.

    `color_bins` (h, w) int: per-pixel histogram bin (0..n_bins-1, the caller may code several
    channels as disjoint bin ranges by passing (h, w, C)); `gradients` (h, w, 3) float32 colour,
    depth and normal gradient strengths; `normals` (h, w, 3); `valid` (h, w) depth validity.
    """
    w = labels.shape[1]
    flat = labels.ravel()
    n = int(flat.max()) + 1
    size = np.bincount(flat, minlength=n).astype(np.float64)
    vs, us = np.divmod(np.arange(flat.size), w)
    bbox = np.empty((n, 4), np.int64)
    bbox[:, :2] = np.iinfo(np.int64).max
    bbox[:, 2:] = -1
    np.minimum.at(bbox[:, 0], flat, us)
    np.minimum.at(bbox[:, 1], flat, vs)
    np.maximum.at(bbox[:, 2], flat, us)
    np.maximum.at(bbox[:, 3], flat, vs)

    bins = color_bins.reshape(flat.size, -1)
    keys = (flat[:, None] * n_bins + bins).ravel()
    color_hist = np.bincount(keys, minlength=n * n_bins).reshape(n, n_bins).astype(np.float32)

    nrm = np.where(valid[..., None], normals, 0.0).reshape(-1, 3)
    normal_sum = np.stack([np.bincount(flat, weights=nrm[:, k], minlength=n) for k in range(3)], axis=1)

    pair_a, pair_b, pair_s = [], [], []
    g = gradients
    for la, lb, ga, gb in (
        (labels[:, :-1], labels[:, 1:], g[:, :-1], g[:, 1:]),
        (labels[:-1, :], labels[1:, :], g[:-1, :], g[1:, :]),
    ):
        cross = la != lb
        pair_a.append(la[cross])
        pair_b.append(lb[cross])
        pair_s.append(np.maximum(ga[cross], gb[cross]))
    a = np.concatenate(pair_a).astype(np.int64)
    b = np.concatenate(pair_b).astype(np.int64)
    s = np.concatenate(pair_s).astype(np.float64)
    pairs, length, strength = _aggregate_edges(np.minimum(a, b), np.maximum(a, b), np.ones(a.size), s, n)
    return RegionGraph(size, bbox, color_hist, normal_sum, pairs, length, strength)


def _aggregate_edges(
    a: np.ndarray, b: np.ndarray, length: np.ndarray, strength: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sum the statistics of parallel edges (a < b given): unique (E, 2) pairs, lengths, strengths."""
    key = a * n + b
    uniq, inverse = np.unique(key, return_inverse=True)
    m = uniq.size
    total_len = np.bincount(inverse, weights=length, minlength=m)
    total_str = np.stack(
        [np.bincount(inverse, weights=strength[:, k], minlength=m) for k in range(strength.shape[1])], axis=1
    )
    return np.stack(np.divmod(uniq, n), axis=1), total_len, total_str


def _boundary_similarity(length: np.ndarray, strength: np.ndarray, scales: BoundaryScales) -> np.ndarray:
    """(E, 3) exp(-mean strength / scale) for colour, depth, normal."""
    scale = np.array([scales.color, scales.depth, scales.normal])
    return np.exp(-strength / (length[:, None] * scale))


def group(graph: RegionGraph, strategy: Strategy, scales: BoundaryScales, image_area: float) -> Hierarchy:
    """Merge the superpixels of `graph` bottom-up under `strategy` (see module docstring).

    `image_area` is the working image's pixel count (size and fill normalisation).
    """
    n0 = graph.n
    cap = 2 * n0
    size = np.zeros(cap)
    size[:n0] = graph.size
    bbox = np.zeros((cap, 4), np.int64)
    bbox[:n0] = graph.bbox
    hist = np.zeros((cap, graph.color_hist.shape[1]), np.float32)
    hist[:n0] = graph.color_hist / graph.color_hist.sum(axis=1, keepdims=True).clip(1e-12)
    normal_sum = np.zeros((cap, 3))
    normal_sum[:n0] = graph.normal_sum
    regions = _Regions(size, bbox, hist, normal_sum, image_area)
    weights = np.array([getattr(strategy, f.name) for f in fields(Strategy)])

    pairs, length, strength = graph.pairs, graph.length, graph.strength
    sim = _similarity(pairs, length, strength, regions, weights, scales)
    owner = np.arange(n0)  # superpixel -> current region
    n_total = n0
    out_ids, out_sp, sims, levels = [], [], [], []
    level = 0
    while pairs.shape[0] > 0:
        ca, cb, chosen_sim = _mutual_best(pairs, sim, n_total)
        m = ca.size
        new = np.arange(n_total, n_total + m)
        wa, wb = size[ca], size[cb]
        size[new] = wa + wb
        bbox[new, :2] = np.minimum(bbox[ca, :2], bbox[cb, :2])
        bbox[new, 2:] = np.maximum(bbox[ca, 2:], bbox[cb, 2:])
        hist[new] = (hist[ca] * wa[:, None] + hist[cb] * wb[:, None]) / (wa + wb)[:, None]
        normal_sum[new] = normal_sum[ca] + normal_sum[cb]

        remap = np.arange(n_total + m)
        remap[ca] = new
        remap[cb] = new
        owner = remap[owner]
        # Only edges at a merged region change: re-key them, drop the merged pairs' own edges,
        # sum parallel edges and recompute their similarity; the others keep theirs.
        ra, rb = remap[pairs[:, 0]], remap[pairs[:, 1]]
        touched = (ra >= n_total) | (rb >= n_total)
        moved = touched & (ra != rb)
        new_pairs, new_length, new_strength = _aggregate_edges(
            np.minimum(ra, rb)[moved], np.maximum(ra, rb)[moved], length[moved], strength[moved], n_total + m
        )
        new_sim = _similarity(new_pairs, new_length, new_strength, regions, weights, scales)
        pairs = np.concatenate([pairs[~touched], new_pairs])
        length = np.concatenate([length[~touched], new_length])
        strength = np.concatenate([strength[~touched], new_strength])
        sim = np.concatenate([sim[~touched], new_sim])

        sp = np.nonzero(owner >= n_total)[0]
        out_ids.append(owner[sp])
        out_sp.append(sp)
        sims.append(chosen_sim)
        levels.append(np.full(m, level))
        n_total += m
        level += 1

    n_new = n_total - n0
    if n_new == 0:
        return Hierarchy(np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64))
    ids = np.concatenate(out_ids) - n0
    sps = np.concatenate(out_sp)
    order = np.lexsort((sps, ids))
    indptr = np.zeros(n_new + 1, np.int64)
    indptr[1:] = np.cumsum(np.bincount(ids, minlength=n_new))
    return Hierarchy(indptr, sps[order], np.concatenate(sims), np.concatenate(levels))


def _mutual_best(pairs: np.ndarray, sim: np.ndarray, n_nodes: int) -> tuple[np.ndarray, ...]:
    """The edges that are the most similar edge of both their ends (ties go to the earlier edge):
    a matching that always holds the globally best edge. Returns its ends and similarities."""
    a, b = pairs[:, 0], pairs[:, 1]
    position = np.empty(sim.size, np.int64)
    position[np.argsort(-sim, kind="stable")] = np.arange(sim.size)
    best = np.full(n_nodes, sim.size)
    np.minimum.at(best, a, position)
    np.minimum.at(best, b, position)
    chosen = np.nonzero((best[a] == position) & (best[b] == position))[0]
    return a[chosen], b[chosen], sim[chosen]


@dataclass
class _Regions:
    """Per-region arrays of one grouping run (rows 0..2N-1, filled as regions are formed);
    `hist` holds normalised colour histograms."""

    size: np.ndarray
    bbox: np.ndarray
    hist: np.ndarray
    normal_sum: np.ndarray
    image_area: float


def _similarity(
    pairs: np.ndarray,
    length: np.ndarray,
    strength: np.ndarray,
    r: _Regions,
    weights: np.ndarray,
    scales: BoundaryScales,
) -> np.ndarray:
    """Weighted sum of the similarity terms (Strategy field order) for the edges `pairs`."""
    a, b = pairs[:, 0], pairs[:, 1]
    sim = np.zeros(a.size)
    w_color, w_bc, w_bd, w_bn, w_normal, w_size, w_fill = weights
    if w_color:
        sim += w_color * np.minimum(r.hist[a], r.hist[b]).sum(axis=1)
    if w_bc or w_bd or w_bn:
        bs = _boundary_similarity(length, strength, scales)
        sim += w_bc * bs[:, 0] + w_bd * bs[:, 1] + w_bn * bs[:, 2]
    if w_normal:
        na = r.normal_sum[a] / np.linalg.norm(r.normal_sum[a], axis=1, keepdims=True).clip(1e-12)
        nb = r.normal_sum[b] / np.linalg.norm(r.normal_sum[b], axis=1, keepdims=True).clip(1e-12)
        sim += w_normal * np.clip((na * nb).sum(axis=1), 0.0, 1.0)
    joint = r.size[a] + r.size[b]
    if w_size:
        sim += w_size * (1.0 - joint / r.image_area)
    if w_fill:
        lo = np.minimum(r.bbox[a, :2], r.bbox[b, :2])
        hi = np.maximum(r.bbox[a, 2:], r.bbox[b, 2:])
        box_area = np.prod(hi - lo + 1, axis=1)
        sim += w_fill * (1.0 - (box_area - joint) / r.image_area)
    return sim
