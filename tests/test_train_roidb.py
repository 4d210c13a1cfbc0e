"""RoI database: IoU matching, class mean sizes, initial boxes and targets, the proposal cache."""

from __future__ import annotations

import numpy as np
import pytest

import a3d.train.roidb as roidb_module
from a3d.runtime.sources.folder import list_frames, read_ground_truth
from a3d.runtime.structures.classes import NUM_CLASSES, class_index
from a3d.runtime.structures.frame import GroundTruth
from a3d.train.config import apply_overrides, load_config
from a3d.train.roidb import build_roidb, class_mean_sizes, label_rois
from tests.test_train_scenes import TINY, write_scenes


def test_label_rois_known_answers():
    boxes = [[0, 0, 10, 10], [20, 0, 30, 10]]
    gt = GroundTruth.from_classes(["chair", "table"], [[0, 0, 3, 1, 1, 1, 0]] * 2, boxes, boxes)
    rois = np.array(
        [
            [0, 0, 10, 10],  # IoU 1 with the chair
            [0, 0, 10, 5],  # 0.5: foreground (>=)
            [0, 0, 10, 2],  # 0.2: background
            [0, 0, 10, 1],  # 0.1: background (>=)
            [0, 0, 10, 0.5],  # 0.05: dropped
            [20, 0, 30, 6],  # 0.6 with the table
            [50, 50, 60, 60],  # no overlap: dropped
        ],
        dtype=float,
    )
    keep, labels, overlaps, gt_index = label_rois(rois, gt, fg_iou=0.5, bg_iou_low=0.1)
    chair, table = class_index("chair") + 1, class_index("table") + 1
    assert keep.tolist() == [True, True, True, True, False, True, False]
    assert labels[keep].tolist() == [chair, chair, 0, 0, table]
    assert gt_index[keep].tolist() == [0, 0, -1, -1, 1]
    np.testing.assert_allclose(overlaps, [1, 0.5, 0.2, 0.1, 0.05, 0.6, 0], atol=1e-7)
    nothing = GroundTruth.from_classes([], np.zeros((0, 7)), np.zeros((0, 4)), np.zeros((0, 4)))
    keep, labels, _, _ = label_rois(rois, nothing, fg_iou=0.5, bg_iou_low=0.1)
    assert not keep.any() and not labels.any()  # no ground truth: no foreground, and no background either


def test_class_mean_sizes_with_absent_classes():
    def gt(classes, sizes):
        boxes = np.zeros((len(classes), 7))
        boxes[:, 3:6] = sizes
        empty = np.zeros((len(classes), 4))
        return GroundTruth.from_classes(classes, boxes, empty, empty)

    sizes = [[0.5, 0.4, 0.9], [2, 1.5, 0.5], [0.7, 0.6, 1.1]]
    means = class_mean_sizes([gt(["chair", "bed"], sizes[:2]), gt(["chair"], sizes[2:])])
    assert means.shape == (NUM_CLASSES, 3)
    np.testing.assert_allclose(means[class_index("chair")], [0.6, 0.5, 1.0])
    np.testing.assert_allclose(means[class_index("bed")], [2, 1.5, 0.5])
    np.testing.assert_allclose(means[class_index("sofa")], np.mean(sizes, axis=0))  # absent: all objects


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return write_scenes(tmp_path_factory.mktemp("roidb") / "frames", 4, seed=1)


def test_roidb_records(scenes, tmp_path):
    config = apply_overrides(load_config("vgg16"), TINY)
    db = build_roidb(scenes, config, tmp_path / "cache")
    truths = {r.name: read_ground_truth(r) for r in list_frames(scenes)}
    np.testing.assert_allclose(db.mean_sizes, class_mean_sizes(list(truths.values())))
    for record in db.records:
        gt = truths[record.name]
        n = len(gt.class_ids)
        # Ground-truth RoIs first, labelled with their own class at IoU 1.
        np.testing.assert_allclose(record.boxes[:n], gt.boxes2d_visible, atol=1e-4)
        assert record.labels[:n].tolist() == (gt.class_ids + 1).tolist()
        np.testing.assert_allclose(record.overlaps[:n], 1.0)
        fg, bg = record.labels > 0, record.labels == 0
        assert fg[: record.num_fg].all() and bg[record.num_fg :].all()  # foreground rows first
        assert (record.overlaps[fg] >= 0.5).all()
        assert ((record.overlaps[bg] >= 0.1) & (record.overlaps[bg] < 0.5)).all()
        assert fg.sum() > n and bg.sum() > 0  # proposals found both
        # Initial boxes: the class mean size, theta 0, centre lifted from the visible segment.
        np.testing.assert_allclose(record.init_boxes[:, 3:6], db.mean_sizes[record.labels[fg] - 1])
        assert (record.init_boxes[:, 6] == 0).all()
        assert record.has_3d[:n].all()
        z, depth_extent = gt.boxes3d[:, 2], gt.boxes3d[:, 4]  # w runs along z (theta 0)
        front, back = z - depth_extent / 2, z + depth_extent / 2
        assert ((record.init_boxes[:n, 2] > front - 0.02) & (record.init_boxes[:n, 2] < back)).all()
        # Targets of the ground-truth RoIs point at their own boxes.
        np.testing.assert_allclose(record.gt_boxes3d[:n], gt.boxes3d)
        np.testing.assert_allclose(record.gt_boxes2d[:n], gt.boxes2d_amodal)


def test_proposal_cache_hits_and_misses(scenes, tmp_path, monkeypatch):
    config = apply_overrides(load_config("vgg16"), TINY)
    cache = tmp_path / "cache"
    first = build_roidb(scenes, config, cache)
    assert len(list(cache.glob("*.npz"))) == 4

    def no_proposals(*args, **kwargs):
        raise AssertionError("proposal stage ran despite a cached result")

    monkeypatch.setattr(roidb_module, "prepare", no_proposals)  # the runtime front end
    again = build_roidb(scenes, config, cache)
    for a, b in zip(first.records, again.records, strict=True):
        np.testing.assert_array_equal(a.boxes, b.boxes)
        np.testing.assert_array_equal(a.init_boxes, b.init_boxes)
    other = apply_overrides(config, ["proposals.min_area=30"])
    with pytest.raises(AssertionError, match="proposal stage ran"):
        build_roidb(scenes, other, cache)  # another proposal config: another cache key


def test_front_end_worker_processes_give_the_serial_result(scenes, tmp_path):
    serial = build_roidb(scenes, apply_overrides(load_config("vgg16"), TINY), tmp_path / "serial")
    config = apply_overrides(load_config("vgg16"), [*TINY, "data.front_end_workers=2"])
    parallel = build_roidb(scenes, config, tmp_path / "parallel")
    assert len(list((tmp_path / "parallel").glob("*.npz"))) == 4  # the workers filled the cache
    assert [r.name for r in parallel.records] == [r.name for r in serial.records]
    for a, b in zip(serial.records, parallel.records, strict=True):
        np.testing.assert_array_equal(a.boxes, b.boxes)
        np.testing.assert_array_equal(a.init_boxes, b.init_boxes)
