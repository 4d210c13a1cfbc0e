"""Training RoIs jittered as a 2D detector's boxes (a3d.train.detector_rois) and their place in the
RoI database."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.sources.folder import read_ground_truth
from a3d.runtime.structures.classes import class_index
from a3d.runtime.structures.geometry import Intrinsics, iou_2d
from a3d.train.config import apply_overrides, load_config
from a3d.train.detector_rois import FLOOR, detector_like_rois, jittered_boxes
from a3d.train.roidb import build_roidb
from tests.helpers.train_scenes import TINY, write_scenes

VISIBLE = np.array([[100.0, 50.0, 200.0, 250.0], [300.0, 100.0, 500.0, 200.0]])


def test_jittered_boxes_overlap_their_object_as_a_detector_does_and_some_take_in_floor() -> None:
    boxes, source = jittered_boxes(VISIBLE, 200, (480, 640), np.random.default_rng(0))
    assert len(boxes) == 400 and np.bincount(source).tolist() == [200, 200]
    iou = iou_2d(boxes, VISIBLE)[np.arange(len(boxes)), source]
    assert 0.6 < np.median(iou) < 0.9  # mostly foreground, not the box itself
    assert 0.05 < np.mean(iou < 0.5) < 0.3  # a few fall to background, as a detector's poor boxes do
    heights = VISIBLE[source, 3] - VISIBLE[source, 1]
    lower = (boxes[:, 3] - VISIBLE[source, 3]) / heights
    assert np.mean(lower > 0.5 * FLOOR) > 0.1  # stretched downwards over the floor
    assert boxes[:, [0, 1]].min() >= -0.5 and boxes[:, 2].max() <= 639.5 and boxes[:, 3].max() <= 479.5


def test_the_same_frame_and_seed_give_the_same_rois_and_another_seed_others() -> None:
    depth = np.full((480, 640), 3.0, np.float32)
    K = Intrinsics(500.0, 500.0, 319.5, 239.5)
    args = (VISIBLE, np.array([class_index("chair"), class_index("table")]), 3)
    later = (depth, depth, K, np.full((19, 3), 0.8))
    a = detector_like_rois("frame_1", *args, 0, *later)
    b = detector_like_rois("frame_1", *args, 0, *later)
    c = detector_like_rois("frame_1", *args, 1, *later)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])


def test_a_box_of_an_object_before_a_wall_lifts_to_the_object_not_the_wall() -> None:
    depth = np.full((240, 320), 4.0, np.float32)
    depth[60:180, 100:220] = 2.0  # the object at 2 m, a wall at 4 m around it
    _, centers, valid = detector_like_rois(
        "f", np.array([[100.0, 60.0, 219.0, 179.0]]), np.array([class_index("chair")]), 20, 0,
        depth, depth, Intrinsics(300.0, 300.0, 159.5, 119.5), np.full((19, 3), 0.6),
    )  # fmt: skip
    assert valid.all() and centers[:, 2] == pytest.approx(np.full(20, 2.0))


def test_the_roi_database_takes_them_after_the_ground_truth_as_foreground_with_3d_targets(tmp_path) -> None:
    folder = write_scenes(tmp_path / "frames", 2, seed=4)
    plain = apply_overrides(load_config("vgg16"), TINY)
    jittered = apply_overrides(plain, ["data.detector_rois=4"])
    a = build_roidb(folder, plain, tmp_path / "cache").records
    b = build_roidb(folder, jittered, tmp_path / "cache").records
    for before, after in zip(a, b, strict=True):
        assert len(after.boxes) > len(before.boxes) and after.num_fg > before.num_fg  # most stay foreground
        assert after.has_3d.all() and np.isfinite(after.init_boxes).all()
        objects = len(read_ground_truth(after.ref).class_ids)  # their own RoIs first, as before
        np.testing.assert_array_equal(after.boxes[:objects], before.boxes[:objects])
