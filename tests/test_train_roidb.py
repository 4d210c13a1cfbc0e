"""RoI database: IoU matching, class mean sizes, initial boxes and targets, the proposal cache."""

from __future__ import annotations

import shutil
import sys
from dataclasses import replace

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.frame_proposals import frame_proposals
from a3d.runtime.frontend.lifting import lift
from a3d.runtime.frontend.proposals import propose
from a3d.runtime.pipeline import PipelineConfig, prepare
from a3d.runtime.sources.folder import (
    list_frames,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    write_intrinsics,
)
from a3d.runtime.sources.proposals_file import PrecomputedProposals, write_precomputed_proposals
from a3d.runtime.structures.classes import NUM_CLASSES, class_index
from a3d.runtime.structures.frame import GroundTruth
from a3d.train.config import apply_overrides, load_config
from a3d.train.loop import train
from a3d.train.roidb import build_roidb, class_mean_sizes, compute_front_end, label_rois
from tests.helpers.train_scenes import TINY, K, write_scenes


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


def test_roidb_of_several_folders(scenes, tmp_path):
    """Frames of two folders (the same names, another camera) train together, each with its own
    folder's intrinsics and its own cache entry; a folder with no annotated frame is an error."""
    config = apply_overrides(load_config("vgg16"), TINY)
    other = write_scenes(tmp_path / "other", 2, seed=5)
    wide = replace(K, fx=K.fx * 0.9, fy=K.fy * 0.9)
    write_intrinsics(other, wide)
    db = build_roidb([scenes, other], config, tmp_path / "cache")
    assert len(db.records) + len(db.skipped) == 6
    by_folder = {
        folder: [r for r in db.records if r.ref.color_path.parent == folder] for folder in (scenes, other)
    }
    assert by_folder[scenes] and by_folder[other]
    assert all(r.folder_intrinsics == K for r in by_folder[scenes])
    assert all(r.folder_intrinsics == wide for r in by_folder[other])
    assert {r.name for r in by_folder[scenes]} & {r.name for r in by_folder[other]}  # names collide
    assert len({r.filled_depth_path for r in db.records}) == len(db.records)  # caches do not
    truths = [read_ground_truth(r) for folder in (scenes, other) for r in list_frames(folder)]
    np.testing.assert_allclose(db.mean_sizes, class_mean_sizes(truths))

    empty = tmp_path / "empty"
    empty.mkdir()
    write_intrinsics(empty, K)
    with pytest.raises(InputError, match="empty: no annotated frames"):
        build_roidb([scenes, empty], config, tmp_path / "cache")


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


def _count_calls(monkeypatch, function) -> list[int]:
    """Wrap ``function`` in every loaded a3d module that holds it; the list grows by one per call."""
    calls: list[int] = []

    def counted(*args, **kwargs):
        calls.append(1)
        return function(*args, **kwargs)

    for module in list(sys.modules.values()):
        if (
            getattr(module, "__name__", "").startswith("a3d.")
            and vars(module).get(function.__name__) is function
        ):
            monkeypatch.setattr(module, function.__name__, counted)
    return calls


def test_the_front_end_runs_once_per_frame_per_run_and_is_cached(scenes, tmp_path, monkeypatch):
    """Hole filling, proposals and lifting run once per frame in a whole training run (RoI
    database and every mini-batch), not at all in a run that finds them cached, and again for
    another proposal configuration (another cache key)."""
    fills = _count_calls(monkeypatch, fill_depth)
    proposals = _count_calls(monkeypatch, frame_proposals)
    lifts = _count_calls(monkeypatch, lift)
    cache = tmp_path / "cache"
    config = apply_overrides(load_config("vgg16"), [*TINY, "solver.iterations=4", f"data.cache_dir={cache}"])
    frames = len(list_frames(scenes))
    train(scenes, tmp_path / "run", config, device="cpu")
    assert (len(fills), len(proposals)) == (frames, frames)
    assert len(lifts) == 2 * frames  # the proposals' segments and the ground-truth segments
    assert len(list(cache.glob("*.filled.npy"))) == frames

    first = build_roidb(scenes, config, cache)
    assert (len(fills), len(proposals), len(lifts)) == (frames, frames, 2 * frames)  # all cached
    train(scenes, tmp_path / "again", config, device="cpu")
    assert (len(fills), len(proposals), len(lifts)) == (frames, frames, 2 * frames)
    other = build_roidb(scenes, apply_overrides(config, ["proposals.min_area=30"]), cache)
    assert (len(fills), len(proposals)) == (2 * frames, 2 * frames)
    assert [r.name for r in other.records] == [r.name for r in first.records]
    for record in first.records:
        filled = np.load(record.filled_depth_path)
        np.testing.assert_array_equal(
            filled, fill_depth(read_frame(record.ref, read_folder_intrinsics(scenes)).depth)
        )


def test_front_end_worker_processes_give_the_serial_result(scenes, tmp_path):
    serial = build_roidb(scenes, apply_overrides(load_config("vgg16"), TINY), tmp_path / "serial")
    config = apply_overrides(load_config("vgg16"), [*TINY, "data.front_end_workers=2"])
    parallel = build_roidb(scenes, config, tmp_path / "parallel")
    assert len(list((tmp_path / "parallel").glob("*.npz"))) == 4  # the workers filled the cache
    assert [r.name for r in parallel.records] == [r.name for r in serial.records]
    for a, b in zip(serial.records, parallel.records, strict=True):
        np.testing.assert_array_equal(a.boxes, b.boxes)
        np.testing.assert_array_equal(a.init_boxes, b.init_boxes)


@pytest.mark.parametrize("cut", [0, 100, -50])
def test_a_proposals_file_cut_short_is_computed_again(scenes, tmp_path, cut):
    """Empty, within the zip header, or without the zip's directory at its end."""
    config = apply_overrides(load_config("vgg16"), TINY)
    cache = tmp_path / "cache"
    first = build_roidb(scenes, config, cache)
    path = sorted(cache.glob("*.npz"))[0]
    whole = path.read_bytes()
    path.write_bytes(whole[:cut])
    again = build_roidb(scenes, config, cache)
    assert path.stat().st_size == len(whole)  # rewritten whole
    for a, b in zip(first.records, again.records, strict=True):
        np.testing.assert_array_equal(a.boxes, b.boxes)
        np.testing.assert_array_equal(a.labels, b.labels)


@pytest.mark.parametrize("form", ["computed", "packed masks", "superpixels"])
def test_the_training_front_end_equals_the_runtime_pipeline(scenes, tmp_path, form):
    """Training lifts the proposals a3d-run lifts: computed ones, or the first max_proposals of a
    NAME.proposals.npz in either segment form."""
    folder = tmp_path / "frames"
    shutil.copytree(scenes, folder)
    config = apply_overrides(load_config("vgg16"), [*TINY, "proposals.max_proposals=5"]).proposals
    intrinsics = read_folder_intrinsics(folder)
    ref = list_frames(folder)[0]
    if form != "computed":
        frame = read_frame(ref, intrinsics)
        computed = propose(
            frame.color, fill_depth(frame.depth), frame.intrinsics, replace(config, max_proposals=9)
        )
        assert len(computed.boxes) > 5
        masks = np.stack([computed.mask(i) for i in range(len(computed))])
        pre = PrecomputedProposals.from_masks(computed.boxes, masks)
        if form == "superpixels":
            pre = PrecomputedProposals(
                boxes=pre.boxes, image_size=pre.image_size, superpixels=computed.superpixels.astype(np.int32),
                indptr=computed.indptr, indices=computed.indices.astype(np.int32),
            )  # fmt: skip
        write_precomputed_proposals(folder / f"{ref.name}.proposals.npz", pre)
        ref = list_frames(folder)[0]
    front, filled = compute_front_end(ref, read_ground_truth(ref), intrinsics, config)
    pipeline = PipelineConfig(np.ones((NUM_CLASSES, 3)), proposals=config)
    prepared = prepare(read_frame(ref, intrinsics, with_proposals=True), pipeline)
    assert 0 < len(front.proposal_boxes) <= 5
    np.testing.assert_array_equal(front.proposal_boxes, prepared.boxes)
    np.testing.assert_array_equal(front.proposal_centers, prepared.centers)
    np.testing.assert_array_equal(filled, fill_depth(prepared.frame.depth))
