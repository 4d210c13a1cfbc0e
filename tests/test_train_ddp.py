"""Data-parallel training: two CPU processes (torchrun, gloo) train a few iterations in sync."""

from __future__ import annotations

import subprocess
import sys

import torch

from a3d.train.checkpoint import load_checkpoint
from a3d.train.loop import read_metrics
from tests.test_train_scenes import TINY, write_scenes


def _train(frames, run, cache, nproc: int) -> subprocess.CompletedProcess:
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={nproc}"]
    launcher = launcher if nproc > 1 else [sys.executable]
    sets = [*TINY, "solver.iterations=4", "log.checkpoint_every=2", f"data.cache_dir={cache}"]
    args = [str(frames), "--out", str(run), "--config", "vgg16", "--device", "cpu",
            *[a for s in sets for a in ("--set", s)]]  # fmt: skip
    command = [*launcher, "-m", "a3d.train.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


def test_two_gloo_processes_stay_in_sync(tmp_path):
    frames = write_scenes(tmp_path / "frames", 4, seed=8)
    cache = tmp_path / "cache"
    ddp = _train(frames, tmp_path / "ddp", cache, nproc=2)
    assert ddp.returncode == 0, ddp.stderr[-3000:]
    records = read_metrics(tmp_path / "ddp" / "metrics.jsonl")
    assert [r["world_size"] for r in records if r["kind"] == "data"] == [2]
    syncs = [r for r in records if r["kind"] == "sync"]
    assert [r["iter"] for r in syncs] == [2, 4]
    for r in syncs:  # both ranks hold the same weights at every checkpoint (the loop also checks)
        assert len(r["digests"]) == 2 and r["digests"][0] == r["digests"][1]
    assert [r["iter"] for r in records if r["kind"] == "train"] == [1, 2, 3, 4]

    # Each rank trained on its own images: the result differs from one process on rank 0's alone.
    single = _train(frames, tmp_path / "single", cache, nproc=1)
    assert single.returncode == 0, single.stderr[-3000:]
    a = load_checkpoint(tmp_path / "ddp" / "checkpoint.pt")["model"]
    b = load_checkpoint(tmp_path / "single" / "checkpoint.pt")["model"]
    assert not all(torch.equal(a[k], b[k]) for k in a)
