"""Mini-batch sampling: foreground fractions, reproducibility from (seed, iteration), epochs, ranks."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.train.sampler import epoch_length, plan_batch, sample_rois, slot_images


@pytest.mark.parametrize(
    ("num_fg", "num_bg", "want_fg", "want_bg"),
    [(100, 1000, 32, 96), (5, 1000, 5, 123), (3, 10, 3, 10), (0, 500, 0, 128), (40, 0, 32, 0)],
)
def test_fast_rcnn_fractions(num_fg, num_bg, want_fg, want_bg):
    labels = np.concatenate([np.full(num_fg, 5), np.zeros(num_bg, np.int64)])
    np.random.default_rng(0).shuffle(labels)
    rois, n_fg = sample_rois(labels, np.random.default_rng(1), rois_per_image=128, fg_fraction=0.25)
    assert n_fg == want_fg and len(rois) == want_fg + want_bg
    assert len(np.unique(rois)) == len(rois)  # without replacement
    assert (labels[rois[:n_fg]] > 0).all() and (labels[rois[n_fg:]] == 0).all()  # foreground first


def test_fractions_over_many_draws_are_uniform():
    labels = np.array([1] * 50 + [0] * 50)
    counts = np.zeros(100)
    for i in range(400):
        rois, _ = sample_rois(labels, np.random.default_rng(i), 20, 0.25)
        counts[rois] += 1
    assert counts[:50].sum() == 400 * 5 and counts[50:].sum() == 400 * 15
    assert counts[:50].min() > 20 and counts[50:].min() > 80  # every RoI gets drawn (40 and 120 expected)


def _plan(iteration, rank=0, world_size=1, seed=3, labels=None):
    labels = labels or [np.array([1] * 10 + [0] * 90)] * 7
    return plan_batch(labels, seed=seed, iteration=iteration, images_per_batch=2, rois_per_image=16,
                      fg_fraction=0.25, flip=True, rank=rank, world_size=world_size)  # fmt: skip


def test_plans_are_a_function_of_seed_and_iteration():
    def key(plans):
        return [(p.image, p.flip, p.rois.tolist()) for p in plans]

    assert key(_plan(11)) == key(_plan(11))
    assert key(_plan(11)) != key(_plan(12)) and key(_plan(11)) != key(_plan(11, seed=4))
    flips = [p.flip for it in range(200) for p in _plan(it)]
    assert 0.4 < np.mean(flips) < 0.6


def test_each_epoch_visits_every_image_once_and_ranks_differ():
    n = 10
    seen = [img for it in range(5) for _, img in slot_images(0, it, n, 2)]
    assert sorted(seen[:n]) == list(range(n))  # iterations 0..4 are exactly epoch 0
    epoch1 = [img for it in range(5, 10) for _, img in slot_images(0, it, n, 2)]
    assert sorted(epoch1) == list(range(n)) and epoch1 != seen
    n = 12  # two ranks x 2 images: 3 iterations per epoch, all images distinct across the ranks
    for start in (0, 3, 6):
        epoch = [img for it in range(start, start + 3) for rank in (0, 1)
                 for _, img in slot_images(0, it, n, 2, rank=rank, world_size=2)]  # fmt: skip
        assert sorted(epoch) == list(range(n))


@pytest.mark.parametrize(("n", "per_batch", "world_size"), [(50, 4, 1), (23, 2, 2), (7, 4, 1), (3, 4, 1)])
def test_shape_groups_fill_whole_batches_and_every_epoch_sees_all_but_a_batch(n, per_batch, world_size):
    groups = np.random.default_rng(n).integers(0, 3, n)  # three frame sizes, unevenly shared
    groups[0] = 3  # a size with a single frame: it can only ride in a mixed batch
    iterations = 40
    batches = [[img for _, img in slot_images(5, it, n, per_batch, rank, world_size, groups)]
               for it in range(iterations) for rank in range(world_size)]  # fmt: skip
    epoch = epoch_length(n, per_batch, grouped=True)
    assert epoch % per_batch == 0 or n < per_batch
    flat = [img for batch in batches for img in batch]
    for start in range(0, len(flat) - epoch + 1, epoch):  # each epoch: distinct images, all but < a batch
        seen = flat[start : start + epoch]
        assert len(set(seen)) == len(seen) and n - len(seen) < per_batch
    if n < per_batch:
        return
    mixed_allowed = sum(np.bincount(groups) % per_batch) // per_batch  # batches of left-overs per epoch
    epochs = len(batches) * per_batch / epoch
    mixed = sum(len(set(groups[b])) > 1 for b in batches)
    assert mixed <= np.ceil(epochs) * mixed_allowed
    assert mixed < len(batches) / 4  # most batches hold one size (random batches would mix almost all)


def test_the_same_images_without_groups_are_one_permutation_an_epoch():
    groups = np.zeros(10, np.int64)
    plain = [img for it in range(5) for _, img in slot_images(0, it, 10, 2)]
    grouped = [img for it in range(5) for _, img in slot_images(0, it, 10, 2, groups=groups)]
    assert sorted(plain) == sorted(grouped) == list(range(10))
