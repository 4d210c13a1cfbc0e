"""Mini-batches: horizontal flip of images, boxes and targets; per-class target normalisation."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.network.network_input import network_inputs, scale_boxes
from a3d.runtime.network.preprocess import color_input
from a3d.runtime.sources.folder import list_frames, read_frame, write_frame, write_intrinsics
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import flip_boxes_2d, flip_boxes_3d, flip_intrinsics, flip_rtilt
from a3d.train.config import apply_overrides, load_config
from a3d.train.dataset import BatchDataset, compute_target_stats, raw_targets
from a3d.train.roidb import build_roidb
from a3d.train.sampler import plan_batch
from tests.helpers.train_scenes import SIZE, TINY, K, render_scene, write_scenes


@pytest.fixture(scope="module")
def db_and_config(tmp_path_factory):
    folder = write_scenes(tmp_path_factory.mktemp("dataset") / "frames", 4, seed=2)
    config = apply_overrides(load_config("vgg16"), TINY)
    return folder, build_roidb(folder, config, folder.parent / "cache"), config


def test_flipped_targets_equal_those_of_the_mirrored_frame(tmp_path):
    """README flip convention end to end: flipping a record's boxes (2D u -> W-1-u, 3D x -> -x,
    theta -> -theta) gives the targets the runtime's lifting produces on the mirrored frame
    (mirrored pixels, cx -> W-1-cx, R_tilt -> F R_tilt F)."""
    color, depth, instances, gt = render_scene(7)
    yawed = gt.boxes3d + np.array([0, 0, 0, 0, 0, 0, 0.3])  # a yaw, so that theta -> -theta is exercised
    gt = GroundTruth.from_classes(gt.classes, yawed, gt.boxes2d_visible, gt.boxes2d_amodal, gt.instance_ids)
    width = SIZE[1]
    plain, mirror = tmp_path / "plain", tmp_path / "mirror"
    write_intrinsics(plain, K)
    write_frame(plain, "f", color, depth, R_tilt=np.eye(3), gt=gt, instances=instances)
    mirrored_gt = GroundTruth.from_classes(
        gt.classes, flip_boxes_3d(gt.boxes3d), flip_boxes_2d(gt.boxes2d_visible, width),
        flip_boxes_2d(gt.boxes2d_amodal, width), gt.instance_ids,
    )  # fmt: skip
    write_intrinsics(mirror, flip_intrinsics(K, width))
    write_frame(mirror, "f", color[:, ::-1], depth[:, ::-1], R_tilt=flip_rtilt(np.eye(3)), gt=mirrored_gt,
                instances=instances[:, ::-1])  # fmt: skip
    config = apply_overrides(load_config("vgg16"), TINY)
    a = build_roidb(plain, config, tmp_path / "cache", mean_sizes=np.full((19, 3), 0.7)).records[0]
    b = build_roidb(mirror, config, tmp_path / "cache", mean_sizes=np.full((19, 3), 0.7)).records[0]
    rows = np.arange(len(gt.class_ids))  # the ground-truth RoIs (proposals are not mirror-symmetric)
    t3d_flipped, t2d_flipped, has_a = raw_targets(a, rows, flip=True)
    t3d_mirror, t2d_mirror, has_b = raw_targets(b, rows, flip=False)
    assert has_a.all() and has_b.all()
    np.testing.assert_allclose(t3d_flipped, t3d_mirror, atol=1e-9)
    np.testing.assert_allclose(t2d_flipped, t2d_mirror, atol=1e-9)
    t3d, t2d, _ = raw_targets(a, rows, flip=False)
    np.testing.assert_allclose(t3d_flipped[:, [0, 6]], -t3d[:, [0, 6]], atol=1e-12)  # dx, dtheta change sign
    np.testing.assert_allclose(t3d_flipped[:, 1:6], t3d[:, 1:6], atol=1e-12)
    np.testing.assert_allclose(t2d_flipped, t2d * [-1, 1, 1, 1], atol=1e-12)


def test_batches_carry_flipped_images_and_boxes(db_and_config):
    folder, db, config = db_and_config
    stats = compute_target_stats(db.records, flip=True)
    dataset = BatchDataset(db.records, stats, config, iterations=50)
    refs = {r.name: r for r in list_frames(folder)}
    checked = set()
    for iteration in range(12):
        batch = dataset[iteration]
        plans = plan_batch([r.labels for r in db.records], seed=config.solver.seed, iteration=iteration,
                           images_per_batch=2, rois_per_image=32, fg_fraction=0.25, flip=True,
                           groups=dataset.groups)  # fmt: skip
        start = 0
        for b, plan in enumerate(plans):
            record = db.records[plan.image]
            frame = read_frame(refs[record.name], K)
            expect = frame.color[:, ::-1] if plan.flip else frame.color
            expect = color_input(np.ascontiguousarray(expect))
            np.testing.assert_array_equal(batch["color"][b].numpy(), expect)
            boxes = record.boxes[plan.rois].astype(np.float64)
            boxes = flip_boxes_2d(boxes, SIZE[1]) if plan.flip else boxes
            rows = slice(start, start + len(plan.rois))
            np.testing.assert_allclose(batch["rois"][rows, 1:].numpy(), boxes, atol=1e-4)
            assert (batch["rois"][rows, 0] == b).all()
            np.testing.assert_array_equal(batch["labels"][rows].numpy(), record.labels[plan.rois])
            assert int((batch["labels"][rows] > 0).sum()) == plan.num_fg == min(8, record.num_fg)
            checked.add(plan.flip)
            start += len(plan.rois)
        assert start == len(batch["labels"])
    assert checked == {True, False}


def test_target_normalisation_round_trip(db_and_config):
    _, db, _ = db_and_config
    stats = compute_target_stats(db.records, flip=True)
    labels, t3d, t2d = [], [], []
    for record in db.records:
        rows = np.flatnonzero(record.has_3d)
        for flip in (False, True):
            a, b, _ = raw_targets(record, rows, flip)
            labels.append(record.labels[rows])
            t3d.append(a)
            t2d.append(b)
    labels, t3d, t2d = np.concatenate(labels), np.concatenate(t3d), np.concatenate(t2d)
    n3d, n2d = stats.normalise_3d(labels, t3d), stats.normalise_2d(labels, t2d)
    for c in np.unique(labels):
        rows = labels == c
        np.testing.assert_allclose(n3d[rows].mean(0), 0, atol=1e-9)
        np.testing.assert_allclose(n3d[rows].std(0)[stats.std3d[c] > 1e-3], 1, atol=1e-9)
        np.testing.assert_allclose(stats.mean3d[c, [0, 6]], 0, atol=1e-12)  # flips cancel dx, dtheta
    # De-normalising the network's per-class layout (N, 20, 7) inverts it exactly.
    rows = np.arange(len(labels))
    per_class = np.zeros((len(labels), 20, 7))
    per_class[rows, labels] = n3d
    np.testing.assert_allclose(stats.denormalise_3d(per_class)[rows, labels], t3d, atol=1e-12)
    per_class2d = np.zeros((len(labels), 20, 4))
    per_class2d[rows, labels] = n2d
    np.testing.assert_allclose(stats.denormalise_2d(per_class2d)[rows, labels], t2d, atol=1e-12)


def test_scaled_inputs_and_boxes_agree():
    color, depth, _, _ = render_scene(3)
    c, d, (sx, sy) = network_inputs(color, fill_depth(depth), 0.5, 10.0)
    assert c.shape == d.shape == (3, 24, 32) and (sx, sy) == (0.5, 0.5)
    extent = np.array([[-0.5, -0.5, SIZE[1] - 0.5, SIZE[0] - 0.5]])
    np.testing.assert_allclose(scale_boxes(extent, sx, sy), [[-0.5, -0.5, 31.5, 23.5]])
    np.testing.assert_allclose(scale_boxes([[1.5, 3.5, 5.5, 7.5]], sx, sy), [[0.5, 1.5, 2.5, 3.5]])
