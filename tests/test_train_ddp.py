"""Data-parallel training: two CPU processes (torchrun, gloo) train a few iterations in sync."""

from __future__ import annotations

import subprocess
import sys

import pytest

from a3d.train.checkpoint import load_checkpoint
from a3d.train.loop import read_metrics
from tests.helpers.train_scenes import tiny_train_args, write_scenes

pytestmark = pytest.mark.slow  # two training processes over gloo


def test_two_gloo_processes_stay_in_sync(tmp_path):
    """torchrun, 2 processes on gloo: 4 iterations, both ranks' weights equal at each checkpoint.

    (That ranks draw different images is a3d.train.sampler's, tested in test_train_sampler.)"""
    frames = write_scenes(tmp_path / "frames", 4, seed=8)
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    cache = tmp_path / "cache"
    run = tmp_path / "ddp"
    args = tiny_train_args(frames, run, cache, "solver.iterations=4", "log.checkpoint_every=2")
    command = [*launcher, "-m", "a3d.train.cli", *args]
    ddp = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert ddp.returncode == 0, ddp.stderr[-3000:]
    records = read_metrics(run / "metrics.jsonl")
    assert [r["world_size"] for r in records if r["kind"] == "data"] == [2]
    syncs = [r for r in records if r["kind"] == "sync"]
    assert [r["iter"] for r in syncs] == [2, 4]
    for r in syncs:  # both ranks hold the same weights at every checkpoint (the loop also checks)
        assert len(r["digests"]) == 2 and r["digests"][0] == r["digests"][1]
    assert [r["iter"] for r in records if r["kind"] == "train"] == [1, 2, 3, 4]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 4
