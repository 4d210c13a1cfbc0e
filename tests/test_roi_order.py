"""The runtime's RoI order (a3d.runtime.network.roi_order): a permutation whose chunks hold
neighbours, and a model that answers the same in any order."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from a3d.runtime.network.roi_order import INTERMEDIATE_COST, POOL_CHUNKS, chunk_bounds, pooling_order


def _union_area(boxes: np.ndarray, order: np.ndarray, chunks: int) -> float:
    """Sum over chunks of (RoIs in the chunk) x (area of the chunk's bounding box)."""
    bounds = chunk_bounds(len(order), chunks)
    total = 0.0
    for start, end in itertools.pairwise(bounds):
        part = boxes[order[start:end]]
        extent = part[:, 2:].max(0) - part[:, :2].min(0)
        total += (end - start) * float(extent[0] * extent[1])
    return total


def test_chunk_bounds_cut_as_the_graph_does() -> None:
    assert chunk_bounds(10, 4).tolist() == [0, 2, 5, 7, 10]
    assert chunk_bounds(0, 3).tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize("count", [0, 1, POOL_CHUNKS, POOL_CHUNKS + 1, 500])
def test_order_is_a_permutation_and_groups_neighbours(count: int) -> None:
    rng = np.random.default_rng(count)
    # small boxes scattered over a 640 x 480 frame, in the proposals' arbitrary order
    corner = rng.uniform(0, 600, (count, 2)) * [1.0, 0.75]
    boxes = np.hstack([corner, corner + rng.uniform(8, 40, (count, 2))])
    order = pooling_order(boxes)
    assert sorted(order.tolist()) == list(range(count))
    if count <= POOL_CHUNKS:
        assert order.tolist() == list(range(count))  # one RoI per chunk at most: nothing to gain
    else:
        identity = np.arange(count)
        assert _union_area(boxes, order, POOL_CHUNKS) < 0.5 * _union_area(boxes, identity, POOL_CHUNKS)


def test_detector_model_answers_in_the_callers_order() -> None:
    """DetectorModel.run hands the network its own order and gives the rows back in the caller's."""
    from a3d.runtime.models import model_path
    from a3d.runtime.network.model import DetectorModel

    model = DetectorModel.load(model_path("live"), threads=1)
    # the bundled graph pools all RoIs at once (pool_chunks 1: no order); said to pool in chunks,
    # the runtime orders its RoIs, which must not change the answers either
    model.metadata = dataclasses.replace(model.metadata, pool_chunks=POOL_CHUNKS)
    rng = np.random.default_rng(0)
    color = rng.uniform(-100, 100, (3, 96, 128)).astype(np.float32)
    depth = rng.uniform(-50, 50, (3, 96, 128)).astype(np.float32)
    corner = rng.uniform(0, 80, (60, 2))
    rois = np.hstack([corner, corner + rng.uniform(8, 40, (60, 2))]).astype(np.float32)
    context = rois * np.float32(1.1)
    assert not np.array_equal(pooling_order(rois), np.arange(60))  # the runtime does reorder these
    got = model.run(color, depth, rois, context)
    reversed_ = model.run(color, depth, rois[::-1].copy(), context[::-1].copy())
    for a, b in zip(got, reversed_, strict=True):
        np.testing.assert_allclose(a, b[::-1], rtol=1e-5, atol=1e-6)
    assert not np.allclose(got[0][0], got[0][1])  # rows differ, so a mix-up would show


def _joint_window_cost(maps: list[np.ndarray], order: np.ndarray) -> float:
    """Sum over chunks and maps of K x w x (h + INTERMEDIATE_COST), the window products' cost
    (their multiply-adds and float intermediate), in 16-pixel cells."""
    total = 0.0
    for start, end in itertools.pairwise(chunk_bounds(len(order))):
        for boxes in maps:
            part = boxes[order[start:end]] / 16
            width, height = part[:, 2:].max(0) - part[:, :2].min(0) + 2
            total += (end - start) * width * (height + INTERMEDIATE_COST)
    return total


def test_the_context_boxes_steer_the_cuts() -> None:
    """Small RoIs whose context boxes reach to the frame's left or right edge, half and half: the
    RoIs alone cannot tell the two kinds apart, and the order that weighs both maps costs less
    on both together."""
    rng = np.random.default_rng(3)
    corner = rng.uniform(0, [600, 440], (500, 2))
    rois = np.hstack([corner, corner + 32])
    context = rois.copy()
    left = rng.random(500) < 0.5
    context[left, 0], context[~left, 2] = 0, 640
    both, alone = pooling_order(rois, context), pooling_order(rois)
    assert sorted(both.tolist()) == list(range(500))
    assert _joint_window_cost([rois, context], both) < 0.95 * _joint_window_cost([rois, context], alone)


def test_a_one_chunk_model_is_fed_as_given(monkeypatch) -> None:
    """pool_chunks 1 (the bundled model): no order to compute, the RoIs go in as they are."""
    from a3d.runtime.models import model_path
    from a3d.runtime.network import model as model_module

    model = model_module.DetectorModel.load(model_path("live"), threads=1)
    assert model.metadata.pool_chunks == 1
    fed = []
    monkeypatch.setattr(model_module, "pooling_order", lambda *a: pytest.fail("ordered a one-chunk model"))
    run = model.session.run
    monkeypatch.setattr(
        model.session, "run", lambda names, feeds: fed.append(feeds["rois"]) or run(names, feeds)
    )
    rois = np.array([[50, 40, 90, 80], [0, 0, 30, 20], [60, 0, 100, 30]], np.float32)
    probs, _, _ = model.run(
        np.zeros((3, 96, 128), np.float32), np.zeros((3, 96, 128), np.float32), rois, rois
    )
    np.testing.assert_array_equal(fed[0], rois)
    assert probs.shape == (3, 20)
