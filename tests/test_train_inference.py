"""The torch reference path: same inputs as training, the runtime's post-processing, raw deltas."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.pipeline import prepare
from a3d.runtime.sources.folder import FolderSource, list_frames
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.train.config import apply_overrides, load_config
from a3d.train.dataset import BatchDataset, TargetStats, compute_target_stats
from a3d.train.inference import TorchDetector, TorchNetwork, write_folder_detections
from a3d.train.model import A3DNet
from a3d.train.roidb import build_roidb
from tests.helpers.train_scenes import TINY, write_scenes


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = write_scenes(tmp_path_factory.mktemp("inference") / "frames", 2, seed=9)
    config = apply_overrides(load_config("vgg16"), [*TINY, "data.input_scale=0.5", "data.flip=false"])
    db = build_roidb(folder, config, folder.parent / "cache")
    torch.manual_seed(0)
    return folder, config, db, A3DNet(config.net)


def test_training_batches_and_the_runtime_pipeline_feed_the_network_alike(setup):
    """Images, RoIs and context RoIs of a training batch (unflipped) equal the runtime's inputs."""
    folder, config, db, _ = setup
    batch = BatchDataset(db.records, compute_target_stats(db.records, False), config, 1)[0]
    source = FolderSource(folder)
    refs = {r.name: r for r in source.refs}
    rows_start = 0
    for b, name in enumerate(batch["frames"]):
        prepared = prepare(source.read(refs[name]), config.pipeline(db.mean_sizes))
        np.testing.assert_array_equal(batch["color"][b].numpy(), prepared.color_input[0])
        np.testing.assert_array_equal(batch["depth"][b].numpy(), prepared.depth_input[0])
        rows = np.flatnonzero(batch["rois"][:, 0].numpy() == b)
        ours = batch["rois"][rows, 1:].numpy()
        theirs = {tuple(np.round(r, 3)): i for i, r in enumerate(prepared.rois)}
        keys = [tuple(np.round(r, 3)) for r in ours]
        matched = [(j, theirs[k]) for j, k in enumerate(keys) if k in theirs]
        assert len(matched) >= len(rows) // 2  # the sampled proposals (ground-truth RoIs are extra)
        for j, i in matched:
            context = batch["context_rois"][rows[j], 1:].numpy()
            np.testing.assert_allclose(context, prepared.context_rois[i], atol=1e-3)
        rows_start += len(rows)
    assert rows_start == len(batch["rois"])


def test_network_answers_raw_deltas(setup):
    _, _, _, model = setup
    rng = np.random.default_rng(0)
    stats = TargetStats(rng.normal(size=(20, 7)), rng.uniform(0.1, 2, (20, 7)), rng.normal(size=(20, 4)),
                        rng.uniform(0.1, 2, (20, 4)))  # fmt: skip
    color = rng.normal(size=(1, 3, 24, 32)).astype(np.float32)
    depth = rng.normal(size=(1, 3, 24, 32)).astype(np.float32)
    rois = np.array([[2, 3, 20, 18], [0, 0, 31, 23]], np.float32)
    probs, d3, d2 = TorchNetwork(model, stats).run(color, depth, rois, rois)
    model.eval()
    with torch.no_grad():
        r = torch.cat([torch.zeros(2, 1), torch.from_numpy(rois)], 1)
        logits, n3, n2 = model(torch.from_numpy(color), torch.from_numpy(depth), r, r)
    np.testing.assert_allclose(probs, torch.softmax(logits.double(), 1).numpy(), atol=1e-6)
    raw3d = n3.double().numpy().reshape(2, NUM_OUTPUTS, 7) * stats.std3d + stats.mean3d
    raw2d = n2.double().numpy().reshape(2, NUM_OUTPUTS, 4) * stats.std2d + stats.mean2d
    np.testing.assert_allclose(d3, raw3d, atol=1e-5)
    np.testing.assert_allclose(d2, raw2d, atol=1e-5)
    _, zero3d, _ = TorchNetwork(model, stats, regress_3d=False).run(color, depth, rois, rois)
    assert not zero3d.any()


def test_without_3d_regression_detections_are_the_initial_boxes(setup, tmp_path):
    folder, config, db, model = setup
    config = apply_overrides(config, ["inference.regress_3d=false"])
    means = np.tile([[0.9, 0.6, 0.8]], (19, 1)) * np.linspace(1, 2, 19)[:, None]  # l >= w: stays canonical
    detector = TorchDetector.build(model, config, compute_target_stats(db.records, False), means)
    out = tmp_path / "detections.jsonl"
    frames, problems = write_folder_detections(detector, folder, out)
    assert not problems and [f.frame for f in frames] == [r.name for r in list_frames(folder)]
    assert sum(len(f.class_ids) for f in frames) > 0
    for det, line in zip(frames, read_detections(out), strict=True):  # the file rounds to 1e-6
        assert len(det.class_ids) <= 19 * config.inference.top_k
        np.testing.assert_allclose(det.boxes3d[:, 3:6], means[det.class_ids], atol=1e-12)
        np.testing.assert_allclose(det.boxes3d[:, 6], 0.0, atol=1e-12)
        assert (np.diff(det.scores) <= 0).all()
        np.testing.assert_allclose(line.boxes3d, det.boxes3d, atol=1e-6)
