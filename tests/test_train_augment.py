"""Training-time augmentation (a3d.train.augment): deterministic per image, colour and depth
changed within their ranges, geometry untouched, and wired into the mini-batches by data.augment."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.train.augment import augment_colour, augment_depth, augment_frame, augment_rng
from a3d.train.config import apply_overrides, load_config
from a3d.train.dataset import BatchDataset, compute_target_stats
from a3d.train.roidb import build_roidb
from tests.helpers.train_scenes import TINY, write_scenes


def _frame(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    color = rng.integers(30, 220, (60, 80, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 5.0, (60, 80)).astype(np.float32)
    depth[:10, :10] = 0.0
    return color, depth


def test_augmentation_is_a_function_of_seed_iteration_and_slot() -> None:
    color, depth = _frame()
    a = augment_frame(augment_rng(0, 7, 1), color, depth)
    b = augment_frame(augment_rng(0, 7, 1), color, depth)
    c = augment_frame(augment_rng(0, 8, 1), color, depth)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0]) and not np.array_equal(a[1], c[1])


def test_colour_changes_within_its_ranges() -> None:
    color, _ = _frame()
    means = []
    for k in range(40):
        out = augment_colour(augment_rng(1, k, 0), color)
        assert out.shape == color.shape and out.dtype == np.uint8
        means.append(out.astype(float).mean() / color.astype(float).mean())
    # exposure up to 0.7 stop either way (in linear light): brightness varies, never wildly
    assert 0.5 < min(means) < 0.95 and 1.05 < max(means) < 1.8


def test_depth_gets_noise_steps_and_holes_but_no_new_depth() -> None:
    _, depth = _frame()
    holes, errors = [], []
    for k in range(40):
        out = augment_depth(augment_rng(2, k, 0), depth)
        assert out.dtype == np.float32 and out.shape == depth.shape
        assert not out[depth == 0].any()  # missing depth stays missing
        both = (out > 0) & (depth > 0)
        errors.append(np.median(np.abs(out[both] - depth[both]) / depth[both]))
        holes.append(np.mean((out == 0) & (depth > 0)))
    assert max(errors) < 0.03 and max(errors) > 0.001  # a few per cent at most, but not nothing
    assert max(holes) > 0.01  # some images lose depth in clumps


@pytest.fixture(scope="module")
def db_and_config(tmp_path_factory):
    folder = write_scenes(tmp_path_factory.mktemp("augment") / "frames", 3, seed=5)
    config = apply_overrides(load_config("vgg16"), TINY)
    return folder, build_roidb(folder, config, folder.parent / "cache"), config


def test_batches_augment_images_only_when_asked(db_and_config) -> None:
    _, db, config = db_and_config
    assert not config.data.augment  # off by default
    stats = compute_target_stats(db.records, flip=True)
    plain = BatchDataset(db.records, stats, config, iterations=4)[2]
    on = apply_overrides(config, ["data.augment=true"])
    augmented = BatchDataset(db.records, stats, on, iterations=4)[2]
    again = BatchDataset(db.records, stats, on, iterations=4)[2]
    assert not np.array_equal(plain["color"].numpy(), augmented["color"].numpy())
    assert not np.array_equal(plain["depth"].numpy(), augmented["depth"].numpy())
    np.testing.assert_array_equal(augmented["color"].numpy(), again["color"].numpy())
    for key in ("rois", "labels", "targets3d", "targets2d", "weights3d"):
        np.testing.assert_array_equal(plain[key].numpy(), augmented[key].numpy())
