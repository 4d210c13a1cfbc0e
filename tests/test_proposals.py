"""Segment proposals: superpixels, hierarchical and pair grouping, near-duplicate removal and the
public propose() contract, on small scenes drawn here (rectangles at known depths and colours in
front of a wall and a floor)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from a3d.runtime.frontend.grouping import (
    BoundaryScales,
    Hierarchies,
    LeafSpans,
    PairConfig,
    Strategy,
    _aggregate_edges,
    build_graph,
    concat_ranges,
    group,
    reduce_forest,
)
from a3d.runtime.frontend.proposals import (
    DEFAULT_STRATEGIES,
    PROPOSAL_STAGES,
    ProposalConfig,
    Proposals,
    _drop_near_duplicates,
    first_of_equal,
    propose,
)
from a3d.runtime.frontend.superpixels import SuperpixelConfig, depth_edges, oversegment
from a3d.runtime.structures.geometry import Intrinsics, iou_2d

H, W = 120, 160
K = Intrinsics(fx=150.0, fy=150.0, cx=79.5, cy=59.5)
# (u0, v0, u1, v1) inclusive pixel rectangles, BGR colour, depth (m), drawn far to near.
OBJECTS = [
    ((10, 20, 55, 70), (40, 160, 40), 2.0),
    ((90, 15, 140, 60), (200, 60, 30), 2.5),
    ((60, 55, 105, 100), (30, 40, 190), 1.5),
    # Same colour as the wall: only depth tells it apart.
    ((20, 80, 45, 110), (150, 150, 150), 1.2),
]


def draw_scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Grey wall at 3 m (upper part) over a brown floor, the OBJECTS in front; mild noise."""
    rng = np.random.default_rng(seed)
    color = np.empty((H, W, 3), np.float32)
    color[:] = (150, 150, 150)
    color[90:] = (60, 90, 120)
    depth = np.full((H, W), 3.0, np.float32)
    depth[90:] = np.linspace(2.9, 2.0, H - 90)[:, None]
    masks = []
    for (u0, v0, u1, v1), bgr, z in OBJECTS:
        m = np.zeros((H, W), bool)
        m[v0 : v1 + 1, u0 : u1 + 1] = True
        color[m] = bgr
        depth[m] = z
        masks.append(m)
    visible = []
    for k, m in enumerate(masks):
        later = np.zeros_like(m)
        for m2 in masks[k + 1 :]:
            later |= m2
        visible.append(m & ~later)
    color += rng.normal(0.0, 2.0, color.shape).astype(np.float32)
    depth *= 1.0 + rng.normal(0.0, 0.002, depth.shape).astype(np.float32)
    return np.clip(color, 0, 255).astype(np.uint8), depth, visible


def mask_box(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.array([xs.min() - 0.5, ys.min() - 0.5, xs.max() + 0.5, ys.max() + 0.5])


@pytest.fixture(scope="module")
def scene() -> tuple[np.ndarray, np.ndarray, list[np.ndarray], Proposals]:
    color, depth, visible = draw_scene()
    return color, depth, visible, propose(color, depth, K, ProposalConfig(min_area=20))


def test_every_object_is_recovered(scene) -> None:
    _, _, visible, props = scene
    gt = np.stack([mask_box(m) for m in visible])
    best = iou_2d(gt, props.boxes).max(axis=1)
    assert (best >= 0.7).all(), best
    # ... and as a segment, not only as a box.
    for m in visible:
        mask_iou = max((props.mask(i) & m).sum() / (props.mask(i) | m).sum() for i in range(len(props)))
        assert mask_iou >= 0.7


def test_boxes_are_the_exact_extent_of_the_masks(scene) -> None:
    props = scene[3]
    for i in range(len(props)):
        np.testing.assert_array_equal(props.boxes[i], mask_box(props.mask(i)))
    np.testing.assert_array_equal(props.areas(), [props.mask(i).sum() for i in range(len(props))])


def test_csr_form_and_ranking(scene) -> None:
    props = scene[3]
    n_sp = int(props.superpixels.max()) + 1
    assert props.superpixels.shape == (H, W) and props.superpixels.dtype == np.int32
    assert np.array_equal(np.unique(props.superpixels), np.arange(n_sp))
    assert props.indptr[0] == 0 and props.indptr[-1] == props.indices.size
    assert (np.diff(props.indptr) > 0).all()
    for i in range(len(props)):
        members = props.members(i)
        assert (np.diff(members) > 0).all()  # sorted, no repeats
    assert np.isfinite(props.scores).all()
    assert (np.diff(props.scores) <= 0).all()


def test_no_duplicates(scene) -> None:
    props = scene[3]
    sets = {tuple(props.members(i)) for i in range(len(props))}
    assert len(sets) == len(props)
    iou = iou_2d(props.boxes, props.boxes)
    np.fill_diagonal(iou, 0.0)
    assert iou.max() <= 0.95


def test_area_filter_and_cap(scene) -> None:
    color, depth, _, props = scene
    assert props.areas().min() >= 20
    big = propose(color, depth, K, ProposalConfig(min_area=500))
    assert len(big) > 0 and big.areas().min() >= 500
    # A capped run is the head of the uncapped ranking.
    capped = propose(color, depth, K, ProposalConfig(min_area=20, max_proposals=7))
    assert len(capped) == 7
    np.testing.assert_array_equal(capped.boxes, props.boxes[:7])
    np.testing.assert_array_equal(capped.scores, props.scores[:7])


def test_ranking_is_deterministic_and_timing_changes_nothing(scene) -> None:
    color, depth, _, props = scene
    timing: dict[str, float] = {}
    again = propose(color, depth, K, ProposalConfig(min_area=20), timing)
    assert tuple(timing) == PROPOSAL_STAGES  # every stage timed, in order
    assert all(seconds >= 0 for seconds in timing.values())
    np.testing.assert_array_equal(again.superpixels, props.superpixels)
    np.testing.assert_array_equal(again.indptr, props.indptr)
    np.testing.assert_array_equal(again.indices, props.indices)
    np.testing.assert_array_equal(again.scores, props.scores)


@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (3, 3), (5, 4), (9, 1)])
@pytest.mark.parametrize("zero_depth", [False, True])
def test_tiny_images_and_missing_depth_never_crash(shape, zero_depth) -> None:
    rng = np.random.default_rng(1)
    color = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    depth = np.zeros(shape, np.float32) if zero_depth else rng.uniform(0.5, 4.0, shape).astype(np.float32)
    props = propose(color, depth, K, ProposalConfig(min_area=1))
    assert len(props) >= 1
    assert props.superpixels.shape == shape
    assert np.isfinite(props.boxes).all() and np.isfinite(props.scores).all()
    # The whole image is one of them (every hierarchy ends there) or it is a single superpixel.
    assert any(props.mask(i).all() for i in range(len(props)))


def test_all_zero_depth_and_single_pixel_segments() -> None:
    color, _, _ = draw_scene()
    color[5, 5] = (0, 0, 255)  # a one-pixel spot
    props = propose(color, np.zeros((H, W), np.float32), K, ProposalConfig(min_area=1))
    assert len(props) > 0
    assert np.isfinite(props.boxes).all() and np.isfinite(props.scores).all()
    # Without depth, colour alone still finds the coloured objects.
    gt = np.stack([mask_box(draw_scene()[2][k]) for k in range(3)])
    assert (iou_2d(gt, props.boxes).max(axis=1) >= 0.7).all()


def test_bad_input_is_rejected() -> None:
    color, depth, _ = draw_scene()
    with pytest.raises(ValueError, match="depth"):
        propose(color, depth[:-1], K)
    with pytest.raises(ValueError, match="depth"):
        propose(color, np.where(depth > 2.5, np.nan, depth).astype(np.float32), K)
    with pytest.raises(ValueError, match="colour"):
        propose(color.astype(np.float32), depth, K)


def test_superpixels_are_connected_and_respect_depth_edges() -> None:
    # Flat grey everywhere: only the depth step (a square 1 m in front) separates the regions.
    lab = np.full((60, 80, 3), 128, np.uint8)
    log_depth = np.full((60, 80), np.log(3.0), np.float32)
    log_depth[20:40, 30:55] = np.log(2.0)
    normals = np.zeros((60, 80, 3), np.float32)
    normals[..., 2] = -1.0
    valid = np.ones((60, 80), bool)
    config = SuperpixelConfig(n_segments=40)
    barrier = depth_edges(log_depth, valid, config)
    labels = oversegment(lab, log_depth, barrier, config)
    n = int(labels.max()) + 1
    assert np.array_equal(np.unique(labels), np.arange(n)) and 20 <= n <= 60
    near = log_depth < np.log(2.5)
    for k in range(n):
        m = labels == k
        assert cv2.connectedComponents(m.view(np.uint8), connectivity=4)[0] == 2
        # No superpixel reaches more than one pixel across the step (barrier pixels are split).
        inner = cv2.erode(near.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        outer = ~cv2.dilate(near.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert not ((m & inner).any() and (m & outer).any())


def two_tone_graph() -> tuple[np.ndarray, object]:
    """A 40x60 image, left half dark, right half light, cut into 6x8 superpixel blocks."""
    h, w = 40, 60
    labels = (np.arange(h)[:, None] // 8) * 8 + np.arange(w)[None, :] // 8
    labels = np.unique(labels, return_inverse=True)[1].reshape(h, w).astype(np.int32)
    lab = np.full((h, w, 3), 128, np.int32)
    lab[:, 32:, 0] = 230
    lab[:, :32, 0] = 20
    bins = (lab * 8) >> 8
    bins += np.arange(3) * 8
    grad = np.zeros((h, w, 3), np.float32)
    grad[:, 31:33, 0] = 100.0
    normals = np.zeros((h, w, 3), np.float32)
    normals[..., 2] = -1
    ones = np.ones((h, w), bool)
    graph = build_graph(labels, bins, 24, grad, np.zeros((h, w), np.float32), ones, normals, ones)
    return labels, graph


def region_members(hier: Hierarchies) -> tuple[np.ndarray, np.ndarray]:
    """The CSR (indptr, sorted indices) of every region of `hier`, through LeafSpans."""
    rows = np.arange(hier.n)
    return LeafSpans.of(hier).members(hier.n_leaves + rows, rows, hier.n, hier.n_superpixels)


def test_hierarchies_are_binary_trees_that_find_the_two_halves() -> None:
    labels, graph = two_tone_graph()
    strategies = (Strategy(color=1.0, size=1.0, fill=1.0), Strategy(boundary_color=1.0, size=1.0))
    hier = group(graph, strategies, BoundaryScales(), float(labels.size))
    indptr, indices = region_members(hier)
    n = graph.n
    left = frozenset(np.unique(labels[:, :32]).tolist())
    right = frozenset(np.unique(labels[:, 32:]).tolist())
    for s in range(len(strategies)):
        rows = np.nonzero(hier.strategy == s)[0]
        regions = [frozenset([k]) for k in range(n)]
        regions += [frozenset(indices[indptr[i] : indptr[i + 1]].tolist()) for i in rows]
        assert len(regions) == 2 * n - 1  # a connected graph merges down to one region
        assert regions[-1] == frozenset(range(n))
        # Every merge joins two earlier, disjoint regions.
        for k in range(n, len(regions)):
            parts = [r for r in regions[:k] if r < regions[k]]
            maximal = [r for r in parts if not any(r < q for q in parts)]
            assert len(maximal) == 2 and maximal[0].isdisjoint(maximal[1])
            assert maximal[0] | maximal[1] == regions[k]
        # The dark and the light half each appear as a region before they are joined.
        assert left in regions and right in regions
    # Run alone, a strategy forms exactly the regions it forms in company.
    alone_indptr, alone_indices = region_members(
        group(graph, strategies[1:], BoundaryScales(), float(labels.size))
    )
    rows = np.nonzero(hier.strategy == 1)[0]
    np.testing.assert_array_equal(np.diff(alone_indptr), np.diff(indptr)[rows])
    np.testing.assert_array_equal(
        alone_indices, np.concatenate([indices[indptr[i] : indptr[i + 1]] for i in rows])
    )


def reference_sets(hier: Hierarchies) -> list[set[int]]:
    """Each region's superpixels, by plain recursion over the merge forest's children."""
    nodes: list[set[int]] = [{leaf % hier.n_superpixels} for leaf in range(hier.n_leaves)]
    for a, b in hier.children.tolist():
        assert nodes[a].isdisjoint(nodes[b])
        nodes.append(nodes[a] | nodes[b])
    return nodes[hier.n_leaves :]


def test_forest_members_and_statistics_match_a_plain_recursion() -> None:
    color, depth, _ = draw_scene(seed=2)
    lab = cv2.cvtColor(color, cv2.COLOR_BGR2Lab)
    log_depth = np.log(depth)
    ones = np.ones(depth.shape, bool)
    config = SuperpixelConfig(n_segments=60)
    labels = oversegment(lab, log_depth, depth_edges(log_depth, ones, config), config)
    bins = (lab.astype(np.int32) * 8 >> 8) + np.arange(3) * 8
    grad = np.random.default_rng(0).random((*depth.shape, 3)).astype(np.float32)
    normals = np.zeros((*depth.shape, 3), np.float32)
    normals[..., 2] = -1.0
    graph = build_graph(labels, bins, 24, grad, log_depth, ones, normals, ones)
    hier = group(graph, DEFAULT_STRATEGIES[:4], BoundaryScales(), float(labels.size))
    sets = reference_sets(hier)
    assert hier.n == 4 * (graph.n - 1)  # every strategy merges the connected graph down to one
    # Members of arbitrary rows, several nodes per row (a pair), sorted.
    rng = np.random.default_rng(1)
    chosen = rng.choice(hier.n, 40, replace=False)
    disjoint_pair = next((a, b) for a in range(hier.n) for b in range(hier.n) if sets[a].isdisjoint(sets[b]))
    nodes = hier.n_leaves + np.array([*chosen, *disjoint_pair])
    rows = np.array([*range(40), 40, 40])
    indptr, indices = LeafSpans.of(hier).members(nodes, rows, 41, hier.n_superpixels)
    expected = [sorted(sets[c]) for c in chosen] + [sorted(sets[disjoint_pair[0]] | sets[disjoint_pair[1]])]
    assert [indices[indptr[i] : indptr[i + 1]].tolist() for i in range(41)] == expected
    # Additive statistics merged along the forest: sums, minima and maxima over the member sets.
    values = rng.integers(-(2**62), 2**62, (graph.n, 3))
    merged = reduce_forest(hier, values, lambda a, b: np.stack([a[:, 0] + b[:, 0],
                           np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 2], b[:, 2])], axis=1))  # fmt: skip
    for k, members in enumerate(sets):
        m = sorted(members)
        wrapped = (int(values[m, 0].astype(object).sum()) + 2**63) % 2**64 - 2**63  # int64 wrap-around
        assert merged[k].tolist() == [wrapped, values[m, 1].min(), values[m, 2].max()]


def test_first_of_equal_keeps_the_first_of_each_distinct_row() -> None:
    rng = np.random.default_rng(4)
    keys = rng.integers(0, 3, (200, 3))
    keys[:, 0] = rng.integers(0, 2, 200)  # many rows share a first column but differ later
    seen: set[tuple[int, ...]] = set()
    expected = []
    for row in map(tuple, keys.tolist()):
        expected.append(row not in seen)
        seen.add(row)
    np.testing.assert_array_equal(first_of_equal(keys), expected)
    unique_first = keys.copy()
    unique_first[:, 0] = np.arange(200) % 50  # equal first columns only where the rows are equal
    unique_first[:, 1:] = unique_first[:, :1]
    np.testing.assert_array_equal(first_of_equal(unique_first), np.arange(200) < 50)
    assert first_of_equal(np.zeros((0, 3), np.int64)).size == 0


def greedy_reference(boxes: np.ndarray, threshold: float) -> list[int]:
    """Plain sequential greedy suppression, best first."""
    kept: list[int] = []
    for i in range(len(boxes)):
        if not kept or iou_2d(boxes[i : i + 1], boxes[kept]).max() <= threshold:
            kept.append(i)
    return kept


@pytest.mark.parametrize("threshold", [0.5, 0.9, 0.95])
@pytest.mark.parametrize("seed", range(4))
def test_near_duplicate_removal_matches_sequential_greedy(seed, threshold) -> None:
    rng = np.random.default_rng(seed)
    base = rng.uniform(0, 100, (40, 2))
    size = rng.uniform(5, 60, (40, 2))
    boxes = np.concatenate([base, base + size], axis=1)
    # Chains of near-copies: each jitters the previous one a little.
    copies = [boxes]
    for _ in range(4):
        copies.append(copies[-1] + rng.normal(0, 0.4, boxes.shape))
    boxes = np.concatenate(copies)[rng.permutation(200)]
    rows = np.arange(200) + 1000
    kept = _drop_near_duplicates(boxes, threshold, rows)
    np.testing.assert_array_equal(kept, np.array(greedy_reference(boxes, threshold)) + 1000)


def test_an_object_cut_in_two_by_an_occluder_is_one_proposal() -> None:
    """A green board behind a full-height red post: its visible part is two disjoint pieces,
    which only the pair combination puts together (with the post, the mask would be too big)."""
    rng = np.random.default_rng(3)
    color = np.empty((H, W, 3), np.float32)
    color[:] = (150, 150, 150)
    depth = np.full((H, W), 3.0, np.float32)
    board = np.zeros((H, W), bool)
    board[30:81, 20:140] = True
    color[board] = (40, 160, 40)
    depth[board] = 2.0
    color[:, 65:95] = (30, 40, 190)
    depth[:, 65:95] = 1.0
    visible = board.copy()
    visible[:, 65:95] = False
    color = np.clip(color + rng.normal(0.0, 2.0, color.shape), 0, 255).astype(np.uint8)

    def best_mask_iou(props: Proposals) -> float:
        return max(
            (props.mask(i) & visible).sum() / (props.mask(i) | visible).sum() for i in range(len(props))
        )

    with_pairs = propose(color, depth, K, ProposalConfig(min_area=20))
    assert best_mask_iou(with_pairs) >= 0.8
    assert iou_2d(mask_box(visible)[None], with_pairs.boxes).max() >= 0.9
    without = propose(color, depth, K, ProposalConfig(min_area=20, pairs=PairConfig(max_pairs=0)))
    assert best_mask_iou(without) < 0.7


def test_concat_ranges_known_answer() -> None:
    np.testing.assert_array_equal(concat_ranges(np.array([5, 0, 9]), np.array([2, 0, 3])), [5, 6, 9, 10, 11])
    assert concat_ranges(np.zeros(0, np.int64), np.zeros(0, np.int64)).size == 0


@pytest.mark.parametrize("n", [50, 70_000])  # 16-bit radix passes, and the comparison sort beyond
def test_parallel_edges_are_summed_in_pair_order(n) -> None:
    rng = np.random.default_rng(n)
    a = rng.integers(0, 20, 300) * (n // 50)
    b = a + 1 + rng.integers(0, 3, 300)
    length = rng.random(300)
    strength = rng.random((300, 3))
    pairs, total_len, total_str = _aggregate_edges(a, b, length, strength, n)
    expected: dict[tuple[int, int], list[float]] = {}
    for i, key in enumerate(zip(a.tolist(), b.tolist(), strict=True)):
        expected.setdefault(key, [0.0] * 4)
        expected[key] = [s + v for s, v in zip(expected[key], [length[i], *strength[i]], strict=True)]
    assert [tuple(p) for p in pairs.tolist()] == sorted(expected)
    np.testing.assert_allclose(
        np.column_stack([total_len, total_str]), [expected[k] for k in sorted(expected)]
    )
