"""Hierarchical and combinatorial grouping of superpixels into segment proposals (RGB-D).

Why this design: selective search (Uijlings et al. 2013) merges the most similar pair of adjacent
regions until one is left and takes every region it ever formed as a proposal; several
similarity mixes ("strategies") diversify the set. A sequential merge loop in Python is too slow
for an edge runtime, so the merging goes in *rounds*, vectorised over the region adjacency
graph: every region whose most similar neighbour also has it as its most similar neighbour
merges with it (a matching of mutual best pairs, which always contains the globally best pair);
two more passes of the same run among the regions still unmatched whose favourite is unmatched
too (their similarities cannot have changed this round), which cuts the number of rounds about
threefold. All strategies run together, as copies of the graph in one disjoint union, so each
round's numpy calls serve all of them. Region statistics are additive (sizes, histograms, sums,
boundary sums), so a merge is a sum and the adjacency update is a re-keying plus `np.bincount`.
The result is the merge forest, not every region's member list (about ten times the superpixels
per strategy): statistics merge along it (`reduce_forest`) and member lists are spelled out only
for the regions that need them (`LeafSpans`).

Similarity terms, each in [0, 1] (1 = merge first):
colour (histogram intersection of Lab histograms), colour/depth/normal boundary (exp of minus
the mean gradient strength along the shared boundary over a scale), normal (cosine of the mean
normals), size (1 - joint size / image size) and fill (1 - bounding-box slack / image size).

MCG (Arbelaez et al. 2014) adds combinations of regions to its hierarchy's; `combine_pairs` adds
disjoint pairs of well-ranked regions, which need not touch: the two halves of an object cut by
an occluder, or the shade and the base of a lamp whose pole is too thin to segment.
"""

from __future__ import annotations

from collections.abc import Callable
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
    `color_hist` holds counts; `normal_sum` sums unit normals where they are defined;
    `depth_sum` sums log depth over the `depth_count` pixels with known depth.
    Edges `pairs` (E, 2) with a < b; `length` counts the 4-neighbour pixel pairs across the shared
    boundary, `strength` (E, 3) sums their colour, depth and normal gradient strengths.
    """

    size: np.ndarray
    bbox: np.ndarray
    color_hist: np.ndarray
    normal_sum: np.ndarray
    depth_sum: np.ndarray
    depth_count: np.ndarray
    pairs: np.ndarray
    length: np.ndarray
    strength: np.ndarray

    @property
    def n(self) -> int:
        return int(self.size.shape[0])


@dataclass
class Hierarchies:
    """The regions formed by merging, all strategies together, in order of creation, as a merge
    forest: its member lists are only spelled out for the few regions that need them
    (LeafSpans), and additive statistics are merged along it (reduce_forest), since the lists of
    all regions together are about ten times the superpixels per strategy.

    Nodes 0..L-1 (L = `n_superpixels` x strategies) are the leaves, node i superpixel
    `i % n_superpixels` of strategy `i // n_superpixels`; node L + k is region k, the union of the
    nodes `children[k]`. The regions of merge round r are `rounds[r]:rounds[r + 1]`; their
    children are from earlier rounds. `strategy` (M,) is the index of the strategy that formed a
    region; `outer` (M, 3) the mean boundary similarity (colour, depth, normal; 1 = no edge)
    along its outline when it was formed (0 for a region with no neighbour left).
    """

    n_superpixels: int
    n_leaves: int
    children: np.ndarray
    rounds: np.ndarray
    strategy: np.ndarray
    outer: np.ndarray

    @property
    def n(self) -> int:
        return int(self.children.shape[0])


def reduce_forest(
    hier: Hierarchies, leaf_values: np.ndarray, merge: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> np.ndarray:
    """(M, ...) per-region values of an additive statistic: `leaf_values` (n_superpixels, ...)
    per superpixel, `merge(a, b)` the value of a union from its two parts' (elementwise rows),
    applied round by round."""
    values = np.empty((hier.n_leaves + hier.n, *leaf_values.shape[1:]), leaf_values.dtype)
    copies = np.broadcast_to(leaf_values, (hier.n_leaves // hier.n_superpixels, *leaf_values.shape))
    values[: hier.n_leaves] = copies.reshape(hier.n_leaves, *leaf_values.shape[1:])
    for lo, hi in zip(hier.rounds[:-1], hier.rounds[1:], strict=True):
        a, b = hier.children[lo:hi, 0], hier.children[lo:hi, 1]
        values[hier.n_leaves + lo : hier.n_leaves + hi] = merge(
            values.take(a, axis=0), values.take(b, axis=0)
        )
    return values[hier.n_leaves :]


@dataclass
class LeafSpans:
    """The leaves of the merge forest in an order where every node's leaves are contiguous:
    node i's are `order[start[i] : start[i] + size[i]]` (a depth-first order)."""

    order: np.ndarray
    start: np.ndarray
    size: np.ndarray

    @classmethod
    def of(cls, hier: Hierarchies) -> LeafSpans:
        """Top-down, round by round from the last: a region's children split its span."""
        n_leaves = hier.n_leaves
        size = np.ones(n_leaves + hier.n, np.int64)
        size[n_leaves:] = reduce_forest(hier, np.ones(hier.n_superpixels, np.int64), np.add)
        is_child = np.zeros(size.size, bool)
        is_child[hier.children.ravel()] = True
        roots = np.flatnonzero(~is_child)
        start = np.zeros(size.size, np.int64)
        start[roots] = np.cumsum(size[roots]) - size[roots]
        for lo, hi in zip(hier.rounds[-2::-1], hier.rounds[:0:-1], strict=True):
            a, b = hier.children[lo:hi, 0], hier.children[lo:hi, 1]
            start[a] = start[n_leaves + lo : n_leaves + hi]
            start[b] = start[a] + size[a]
        order = np.empty(n_leaves, np.int64)
        order[start[:n_leaves]] = np.arange(n_leaves)
        return cls(order, start, size)

    def members(
        self, nodes: np.ndarray, rows: np.ndarray, n_rows: int, n_superpixels: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """CSR (indptr, sorted superpixel ids) of `n_rows` rows, row `rows[i]` holding the
        superpixels of node `nodes[i]` (a row may take several nodes, which must be disjoint).
        Sorted without a sort: a boolean row x superpixel matrix read back in row-major order,
        in blocks of bounded size."""
        superpixel = self.order[concat_ranges(self.start[nodes], self.size[nodes])] % n_superpixels
        owner = np.repeat(rows, self.size[nodes])
        block = max(1, _MATRIX_CELLS // max(1, n_superpixels))
        indices = []
        for first in range(0, n_rows, block):
            inside = (owner >= first) & (owner < first + block)
            matrix = np.zeros((min(block, n_rows - first), n_superpixels), bool)
            matrix[owner[inside] - first, superpixel[inside]] = True
            indices.append(np.flatnonzero(matrix) % n_superpixels)
        indptr = np.zeros(n_rows + 1, np.int64)
        indptr[1:] = np.cumsum(np.bincount(owner, minlength=n_rows))
        return indptr, np.concatenate(indices) if indices else np.zeros(0, np.int64)


_MATRIX_CELLS = 1 << 24
"""The largest boolean matrix LeafSpans.members fills at once (16 MB)."""


def concat_ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The concatenation of arange(s, s + c) for each (s, c): CSR row gathering, vectorised."""
    counts = np.asarray(counts, np.int64)
    offsets = np.cumsum(counts) - counts
    return np.arange(counts.sum()) + np.repeat(np.asarray(starts, np.int64) - offsets, counts)


def build_graph(
    labels: np.ndarray,
    color_bins: np.ndarray,
    n_bins: int,
    gradients: np.ndarray,
    log_depth: np.ndarray,
    depth_valid: np.ndarray,
    normals: np.ndarray,
    normal_valid: np.ndarray,
) -> RegionGraph:
    """Statistics of the superpixels `labels` (h, w) int32 0..N-1.

    `color_bins` (h, w) int: per-pixel histogram bin (0..n_bins-1, the caller may code several
    channels as disjoint bin ranges by passing (h, w, C)); `gradients` (h, w, 3) float32 colour,
    depth and normal gradient strengths; `log_depth` (h, w) with `depth_valid`; `normals`
    (h, w, 3) with `normal_valid`.
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

    nrm = np.where(normal_valid[..., None], normals, 0.0).reshape(-1, 3)
    normal_sum = np.stack([np.bincount(flat, weights=nrm[:, k], minlength=n) for k in range(3)], axis=1)
    depth_sum = np.bincount(flat, weights=np.where(depth_valid, log_depth, 0.0).ravel(), minlength=n)
    depth_count = np.bincount(flat, weights=depth_valid.ravel(), minlength=n)

    pair_a, pair_b, pair_s = [], [], []
    g = gradients
    for la, lb, ga, gb in (
        (labels[:, :-1], labels[:, 1:], g[:, :-1], g[:, 1:]),
        (labels[:-1, :], labels[1:, :], g[:-1, :], g[1:, :]),
    ):
        cross = la != lb
        pair_a.append(la[cross])
        pair_b.append(lb[cross])
        pair_s.append(np.maximum(ga, gb).reshape(-1, 3).compress(cross.ravel(), axis=0))  # 2-D masks: slow
    a = np.concatenate(pair_a).astype(np.int64)
    b = np.concatenate(pair_b).astype(np.int64)
    s = np.concatenate(pair_s).astype(np.float64)
    pairs, length, strength = _aggregate_edges(np.minimum(a, b), np.maximum(a, b), np.ones(a.size), s, n)
    return RegionGraph(size, bbox, color_hist, normal_sum, depth_sum, depth_count, pairs, length, strength)


def _aggregate_edges(
    a: np.ndarray, b: np.ndarray, length: np.ndarray, strength: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sum the statistics of parallel edges (a < b < n given): unique (E, 2) pairs in (a, b)
    order, lengths, strengths."""
    order = _pair_order(a, b, n)
    sa, sb = a[order], b[order]
    first = np.ones(order.size, bool)
    first[1:] = (sa[1:] != sa[:-1]) | (sb[1:] != sb[:-1])
    inverse = np.empty(order.size, np.int64)
    inverse[order] = np.cumsum(first) - 1
    m = int(first.sum())
    total_len = np.bincount(inverse, weights=length, minlength=m)
    total_str = np.stack(
        [np.bincount(inverse, weights=strength[:, k], minlength=m) for k in range(strength.shape[1])], axis=1
    )
    return np.stack([sa[first], sb[first]], axis=1), total_len, total_str


def _pair_order(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """An order sorting the pairs (a, b) of ids below `n` by a, then b: two passes of numpy's
    radix sort (stable, linear) on 16-bit ids where they fit, one comparison sort otherwise."""
    if n > 1 << 16:
        return np.argsort(a * n + b, kind="stable")
    by_b = np.argsort(b.astype(np.uint16), kind="stable")
    return by_b[np.argsort(a[by_b].astype(np.uint16), kind="stable")]


def _boundary_similarity(length: np.ndarray, strength: np.ndarray, scales: BoundaryScales) -> np.ndarray:
    """(E, 3) exp(-mean strength / scale) for colour, depth, normal."""
    scale = np.array([scales.color, scales.depth, scales.normal])
    return np.exp(-strength / (length[:, None] * scale))


def outer_similarity(graph: RegionGraph, scales: BoundaryScales) -> np.ndarray:
    """(N, 3) mean boundary similarity of each superpixel to all its neighbours (0 if none)."""
    similarity = _boundary_similarity(graph.length, graph.strength, scales)
    return _outer(graph.pairs, graph.length, similarity, 0, graph.n)


def _outer(pairs: np.ndarray, length: np.ndarray, similarity: np.ndarray, first: int, m: int) -> np.ndarray:
    """(m, 3) length-weighted mean boundary `similarity` (E, 3) of the nodes first..first+m-1
    over the edges given (ends outside that range are ignored)."""
    ends = pairs.ravel() - first
    at = np.flatnonzero((ends >= 0) & (ends < m))  # edge ends in edge order, as bincount sums them
    ends, edge = ends[at], at >> 1
    total_len = np.bincount(ends, weights=length[edge], minlength=m)
    weighted = similarity.take(edge, axis=0) * length[edge, None]
    total = np.stack([np.bincount(ends, weights=weighted[:, k], minlength=m) for k in range(3)], 1)
    return total / np.maximum(total_len, 1e-12)[:, None]


def group(
    graph: RegionGraph, strategies: tuple[Strategy, ...], scales: BoundaryScales, image_area: float
) -> Hierarchies:
    """Merge the superpixels of `graph` bottom-up under each strategy (see module docstring):
    every strategy forms N - 1 regions per connected component of N superpixels. `image_area` is
    the working image's pixel count (size and fill normalisation).
    """
    n0, k = graph.n, len(strategies)
    cap = 2 * n0 * k
    size = np.zeros(cap)
    size[: n0 * k] = np.tile(graph.size, k)
    bbox = np.zeros((cap, 4), np.int64)
    bbox[: n0 * k] = np.tile(graph.bbox, (k, 1))
    hist = np.zeros((cap, graph.color_hist.shape[1]), np.float32)
    hist[: n0 * k] = np.tile(
        graph.color_hist / graph.color_hist.sum(axis=1, keepdims=True).clip(1e-12), (k, 1)
    )
    normal_sum = np.zeros((cap, 3))
    normal_sum[: n0 * k] = np.tile(graph.normal_sum, (k, 1))
    node_strategy = np.zeros(cap, np.int64)
    node_strategy[: n0 * k] = np.repeat(np.arange(k), n0)
    regions = _Regions(size, bbox, hist, normal_sum, image_area)
    weights = np.array([[getattr(st, f.name) for f in fields(Strategy)] for st in strategies], float)
    weights = weights.reshape(k, len(fields(Strategy)))

    # Every strategy starts from the same superpixel graph: its similarity terms once, weighted k ways.
    pairs = (graph.pairs[None] + (np.arange(k) * n0)[:, None, None]).reshape(-1, 2)
    length = np.tile(graph.length, k)
    strength = np.tile(graph.strength, (k, 1))
    bs = _boundary_similarity(graph.length, graph.strength, scales)
    terms = _similarity_terms(graph.pairs, bs, regions, weights.max(axis=0, initial=0.0)[:, None])
    sim = np.concatenate([_weighted(terms, w[:, None]) for w in weights]) if k else np.zeros(0)
    n_total = n0 * k
    children, rounds, outers = [], [0], []
    while pairs.shape[0] > 0:
        ca, cb = _mutual_best(pairs, sim, n_total)
        m = ca.size
        new = np.arange(n_total, n_total + m)
        wa, wb = size[ca], size[cb]
        size[new] = wa + wb
        # Row gathers by take (faster than fancy indexing for 2-D rows).
        box_a, box_b = bbox.take(ca, axis=0), bbox.take(cb, axis=0)
        bbox[new, :2] = np.minimum(box_a[:, :2], box_b[:, :2])
        bbox[new, 2:] = np.maximum(box_a[:, 2:], box_b[:, 2:])
        hist[new] = (hist.take(ca, axis=0) * wa[:, None] + hist.take(cb, axis=0) * wb[:, None]) / (wa + wb)[
            :, None
        ]
        normal_sum[new] = normal_sum.take(ca, axis=0) + normal_sum.take(cb, axis=0)
        node_strategy[new] = node_strategy[ca]
        children.append(np.stack([ca, cb], axis=1))
        rounds.append(rounds[-1] + m)

        remap = np.arange(n_total + m)
        remap[ca] = new
        remap[cb] = new
        # Only edges at a merged region change: re-key them, drop the merged pairs' own edges,
        # sum parallel edges and recompute their similarity; the others keep theirs.
        ra, rb = remap[pairs[:, 0]], remap[pairs[:, 1]]
        touched = (ra >= n_total) | (rb >= n_total)
        moved = touched & (ra != rb)
        new_pairs, new_length, new_strength = _aggregate_edges(
            np.minimum(ra, rb)[moved],
            np.maximum(ra, rb)[moved],
            length[moved],
            strength.compress(moved, axis=0),
            n_total + m,
        )
        edge_weights = weights.T[:, node_strategy[new_pairs[:, 0]]]
        bs = _boundary_similarity(new_length, new_strength, scales)
        new_sim = _weighted(_similarity_terms(new_pairs, bs, regions, edge_weights), edge_weights)
        outers.append(_outer(new_pairs, new_length, bs, n_total, m))
        # Rows picked by compress: boolean indexing of 2-D arrays is several times slower.
        kept = ~touched
        pairs = np.concatenate([pairs.compress(kept, axis=0), new_pairs])
        length = np.concatenate([length[kept], new_length])
        strength = np.concatenate([strength.compress(kept, axis=0), new_strength])
        sim = np.concatenate([sim[kept], new_sim])
        n_total += m

    return Hierarchies(
        n_superpixels=n0,
        n_leaves=n0 * k,
        children=np.concatenate(children) if children else np.zeros((0, 2), np.int64),
        rounds=np.asarray(rounds, np.int64),
        strategy=node_strategy[n0 * k : n_total],
        outer=np.concatenate(outers) if outers else np.zeros((0, 3)),
    )


def _mutual_best(
    pairs: np.ndarray, sim: np.ndarray, n_nodes: int, passes: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """A matching of mutually most similar edges: the edges that are the most similar edge of
    both their ends (ties go to the lowest index), which always includes the globally best edge.
    Then, `passes - 1` times, the same among the edges between still unmatched regions whose
    own most similar neighbour is still unmatched too: their similarities are unaffected by
    this round's merges, and a region whose favourite was just merged waits for the next round
    (it may like the merged region even better)."""
    a, b = pairs[:, 0], pairs[:, 1]
    edges = np.arange(sim.size)
    taken = np.zeros(n_nodes, bool)
    chosen = []
    favourite = None
    for _ in range(passes):
        ea, eb, es = a[edges], b[edges], sim[edges]
        best = np.full(n_nodes, -np.inf)
        np.maximum.at(best, ea, es)
        np.maximum.at(best, eb, es)
        candidate = np.nonzero((es == best[ea]) & (es == best[eb]))[0]
        first = np.full(n_nodes, sim.size)
        np.minimum.at(first, ea[candidate], candidate)
        np.minimum.at(first, eb[candidate], candidate)
        pick = candidate[(first[ea[candidate]] == candidate) & (first[eb[candidate]] == candidate)]
        chosen.append(edges[pick])
        if favourite is None:
            # Each region's most similar neighbour over all its edges (lowest edge index on ties).
            top = np.nonzero(es == best[ea])[0], np.nonzero(es == best[eb])[0]
            favourite = np.full(n_nodes, -1)
            favourite[ea[top[0][::-1]]] = eb[top[0][::-1]]
            favourite[eb[top[1][::-1]]] = ea[top[1][::-1]]
        taken[ea[pick]] = True
        taken[eb[pick]] = True
        # Every edge end has a favourite (set in the first pass over all edges).
        waiting = taken[ea] | taken[favourite[ea]] | taken[eb] | taken[favourite[eb]]
        edges = edges[~waiting]
        if edges.size == 0:
            break
    picked = np.concatenate(chosen)
    return a[picked], b[picked]


@dataclass
class _Regions:
    """Per-region arrays of one grouping run (rows 0..2N-1, filled as regions are formed);
    `hist` holds normalised colour histograms."""

    size: np.ndarray
    bbox: np.ndarray
    hist: np.ndarray
    normal_sum: np.ndarray
    image_area: float


def _similarity_terms(
    pairs: np.ndarray, boundary: np.ndarray, r: _Regions, weights: np.ndarray
) -> np.ndarray:
    """(7, E) similarity terms of the edges `pairs` in Strategy field order, `boundary` (E, 3)
    their boundary similarities; `weights` (7, E) or (7, 1): a term is only computed for the
    edges that weigh it (0 elsewhere), the costlier ones only for those edges. Rows, not
    columns, so that every term is a contiguous array."""
    a, b = pairs[:, 0], pairs[:, 1]
    weights = np.broadcast_to(weights, (weights.shape[0], a.size))
    terms = np.zeros((7, a.size))
    terms[1:4] = boundary.T
    joint = r.size[a] + r.size[b]
    terms[5] = 1.0 - joint / r.image_area
    e = np.nonzero(weights[0])[0]
    if e.size:
        common = r.hist.take(a[e], axis=0)
        np.minimum(common, r.hist.take(b[e], axis=0), out=common)
        terms[0, e] = common.sum(axis=1)
    e = np.nonzero(weights[4])[0]
    if e.size:
        na, nb = r.normal_sum.take(a[e], axis=0).T, r.normal_sum.take(b[e], axis=0).T
        dot = na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]
        norms = (na[0] * na[0] + na[1] * na[1] + na[2] * na[2]) * (
            nb[0] * nb[0] + nb[1] * nb[1] + nb[2] * nb[2]
        )
        terms[4, e] = np.clip(dot / np.sqrt(norms).clip(1e-12), 0.0, 1.0)
    e = np.nonzero(weights[6])[0]
    if e.size:
        ba, bb = r.bbox.take(a[e], axis=0).T, r.bbox.take(b[e], axis=0).T
        width = np.maximum(ba[2], bb[2]) - np.minimum(ba[0], bb[0]) + 1
        height = np.maximum(ba[3], bb[3]) - np.minimum(ba[1], bb[1]) + 1
        terms[6, e] = 1.0 - (width * height - joint[e]) / r.image_area
    return terms


def _weighted(terms: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(E,) the weighted sum of the (7, E) similarity terms (`weights` (7, E) or (7, 1)),
    boundary terms first, then size, colour, normal and fill (a fixed order, so equal terms
    give bit-equal similarities)."""
    sim = weights[1] * terms[1] + weights[2] * terms[2] + weights[3] * terms[3]
    for c in (5, 0, 4, 6):
        sim += weights[c] * terms[c]
    return sim


@dataclass(frozen=True)
class PairConfig:
    """Combinations of two regions (MCG-style combinatorial grouping): an object cut in pieces by
    an occluder (a chair behind a table) or joined by a part too thin to segment (a lamp's pole)
    is the union of two regions that need not touch.

    `parts`: how many of the best-ranked regions may pair; `max_pairs`: how many pairs are kept;
    `depth`: largest difference of the parts' mean log depth; `color`: largest distance of their
    mean Lab colours (OpenCV 8-bit Lab units); `spread`: largest ratio of the union's box area to
    the sum of the parts'; `penalty`: subtracted from a pair's score (the lower of its parts').
    """

    parts: int = 300
    max_pairs: int = 400
    depth: float = 0.1
    color: float = 25.0
    spread: float = 3.0
    penalty: float = 0.5


def combine_pairs(
    graph: RegionGraph,
    indptr: np.ndarray,
    indices: np.ndarray,
    boxes: np.ndarray,
    score: np.ndarray,
    bin_centres: np.ndarray,
    config: PairConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of candidate regions (best first, at most `config.parts` of them: the caller's cut;
    CSR `indptr`/`indices` of sorted superpixels of `graph`) that are disjoint, close in depth and
    colour and compact together.

    `boxes` (T, 4) and `score` (T,) are per candidate; `bin_centres` (B,) the Lab value of each
    colour-histogram bin. Returns the pairs as two (P,) candidate indices i < j and their scores
    (the lower of the two parts' minus `penalty`), at most `max_pairs` of them, best first.
    """
    t = indptr.size - 1
    if t < 2 or config.max_pairs <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    owner = np.repeat(np.arange(t), np.diff(indptr))
    n_channels = 3
    per_bin = graph.color_hist.shape[1] // n_channels
    lab_sum = (graph.color_hist * bin_centres).reshape(graph.n, n_channels, per_bin).sum(axis=2)
    size = np.bincount(owner, weights=graph.size[indices], minlength=t)
    lab = np.stack([np.bincount(owner, weights=lab_sum[indices, c], minlength=t) for c in range(3)], 1)
    lab /= size[:, None]
    depth_n = np.bincount(owner, weights=graph.depth_count[indices], minlength=t)
    log_z = np.bincount(owner, weights=graph.depth_sum[indices], minlength=t) / np.maximum(depth_n, 1.0)

    # Pairwise, one coordinate / channel at a time (2-D arrays, not strided 3-D reductions).
    x1, y1, x2, y2 = boxes.T
    box_area = (x2 - x1) * (y2 - y1)
    union_w = np.maximum(x2[:, None], x2[None, :]) - np.minimum(x1[:, None], x1[None, :])
    union_area = union_w * (np.maximum(y2[:, None], y2[None, :]) - np.minimum(y1[:, None], y1[None, :]))
    gap = [lab[:, None, c] - lab[None, :, c] for c in range(3)]
    color_gap = gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]
    ok = (
        (np.abs(log_z[:, None] - log_z[None, :]) <= config.depth)
        & ((depth_n[:, None] > 0) == (depth_n[None, :] > 0))
        & (color_gap <= config.color**2)
        & (union_area <= config.spread * (box_area[:, None] + box_area[None, :]))
    )
    i, j = np.nonzero(np.triu(ok, 1))
    # Only disjoint parts pair up (a union with an overlap is not a new combination).
    member_matrix = np.zeros((t, graph.n), bool)
    member_matrix[owner, indices] = True
    bits = np.packbits(member_matrix, axis=1)
    disjoint = ~(bits.take(i, axis=0) & bits.take(j, axis=0)).any(axis=1)
    i, j = i[disjoint], j[disjoint]
    pair_score = np.minimum(score[i], score[j]) - config.penalty
    best = np.argsort(-pair_score, kind="stable")[: config.max_pairs]
    return i[best], j[best], pair_score[best]
