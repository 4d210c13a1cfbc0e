"""Checkpoints: exact round trip, refusals with a one-line message naming the file, crash safety."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from a3d.train.checkpoint import (
    CheckpointError,
    checkpoint_config,
    load_checkpoint,
    load_trained,
    save_checkpoint,
)
from a3d.train.config import TrainConfig
from a3d.train.dataset import TargetStats
from a3d.train.model import A3DNet, NetConfig


def _payload(value: float) -> dict:
    return {
        "iteration": 7,
        "config": '{"solver": {"lr": 0.005}}',
        "model": {"fc.weight": torch.full((3, 4), value), "bn.num_batches_tracked": torch.tensor(3)},
        "optimizer": {
            "state": {0: {"momentum_buffer": torch.ones(2)}},
            "param_groups": [{"lr": 0.1, "params": [0]}],
        },
        "classes": ["bathtub", "bed"],
    }


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "run" / "checkpoint.pt"
    save_checkpoint(path, _payload(1.5))
    loaded = load_checkpoint(path)
    assert loaded["format"] == "a3d-checkpoint" and loaded["iteration"] == 7
    assert torch.equal(loaded["model"]["fc.weight"], torch.full((3, 4), 1.5))
    assert loaded["optimizer"]["state"][0]["momentum_buffer"].tolist() == [1.0, 1.0]
    assert not [p for p in path.parent.iterdir() if p.name != "checkpoint.pt"]  # no temporary left


def test_objects_that_need_pickle_are_refused_before_writing(tmp_path):
    with pytest.raises(TypeError, match=r"checkpoint\.extra: Exception"):
        save_checkpoint(tmp_path / "c.pt", {**_payload(0.0), "extra": Exception("x")})
    assert not (tmp_path / "c.pt").exists()


def _one_line_error(path) -> str:
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    return message


def test_corrupted_and_truncated_files_are_refused(tmp_path):
    good = tmp_path / "good.pt"
    save_checkpoint(good, _payload(2.0))
    data = good.read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(data[: len(data) // 2])
    assert "corrupted, truncated" in _one_line_error(truncated)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(os.urandom(4096))
    assert "corrupted, truncated" in _one_line_error(garbage)
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    _one_line_error(empty)
    assert "no such checkpoint" in _one_line_error(tmp_path / "missing.pt")


class _Marker:
    """Unpickling this would create a file: proof that loading ran code."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_pickles_that_run_code_are_refused_and_not_run(tmp_path):
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.pt"
    torch.save({"format": "a3d-checkpoint", "version": 1, "model": _Marker(str(marker))}, evil)
    assert "not a weights-only checkpoint" in _one_line_error(evil)
    plain = tmp_path / "plain.pkl"
    plain.write_bytes(pickle.dumps(_Marker(str(marker))))
    _one_line_error(plain)
    assert not marker.exists()


def test_non_a3d_files_are_refused(tmp_path):
    foreign = tmp_path / "vgg16.pth"
    torch.save({"features.0.weight": torch.zeros(1)}, foreign)
    assert "not an a3d checkpoint" in _one_line_error(foreign)
    future = tmp_path / "future.pt"
    torch.save({"format": "a3d-checkpoint", "version": 99, "model": {}}, future)
    assert "version 99" in _one_line_error(future)


_CRASH = """
import os, signal, sys, torch
import a3d.train.checkpoint as ck
path, mode = sys.argv[1], sys.argv[2]
if mode == "before-rename":      # the new file is complete and fsync'ed, the rename never happens
    ck.os.replace = lambda *a: os.kill(os.getpid(), signal.SIGKILL)
else:                            # killed in the middle of writing the new file
    real_save = torch.save
    def half_save(obj, f):
        f.write(b"PK\\x03\\x04 half a zip")
        f.flush()
        os.kill(os.getpid(), signal.SIGKILL)
    ck.torch.save = half_save
ck.save_checkpoint(path, {"iteration": 2, "config": "{}", "model": {"w": torch.full((3,), 2.0)}})
"""


@pytest.mark.parametrize("mode", ["before-rename", "mid-write"])
def test_kill_during_a_checkpoint_write_keeps_the_previous_one(tmp_path, mode):
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, {"iteration": 1, "config": "{}", "model": {"w": torch.full((3,), 1.0)}})
    crash = [sys.executable, "-c", textwrap.dedent(_CRASH), str(path), mode]
    proc = subprocess.run(crash, capture_output=True)
    assert proc.returncode == -signal.SIGKILL
    loaded = load_checkpoint(path)
    assert loaded["iteration"] == 1 and torch.equal(loaded["model"]["w"], torch.full((3,), 1.0))
    # The next save succeeds and clears what the killed one left.
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "checkpoint.pt"]
    assert len(leftovers) == 1 and leftovers[0].startswith(".checkpoint.pt.tmp-")
    save_checkpoint(path, {"iteration": 3, "config": "{}", "model": {"w": torch.zeros(3)}})
    assert load_checkpoint(path)["iteration"] == 3
    assert [p.name for p in tmp_path.iterdir()] == ["checkpoint.pt"]


def test_load_trained_gives_the_network_and_refuses_an_unusable_checkpoint(tmp_path):
    config = TrainConfig(net=NetConfig(width=0.0625, fuse_channels=16, fc6=32, fc7=32))
    net = A3DNet(config.net)
    sizes = torch.rand(19, 3, dtype=torch.float64) + 0.5
    payload = {"iteration": 1, "config": config.to_json(), "model": net.state_dict(),
               "target_stats": TargetStats.identity().to_tensors(), "mean_sizes": sizes}  # fmt: skip
    save_checkpoint(tmp_path / "good.pt", payload)
    trained = load_trained(tmp_path / "good.pt")
    assert trained.config == config and not trained.net.training
    np.testing.assert_array_equal(trained.mean_sizes, sizes.numpy())
    for name, tensor in net.state_dict().items():
        assert torch.equal(trained.net.state_dict()[name], tensor)
    assert checkpoint_config(tmp_path / "good.pt") == config

    save_checkpoint(tmp_path / "no_stats.pt", {k: v for k, v in payload.items() if k != "target_stats"})
    with pytest.raises(CheckpointError, match=r"no_stats.pt: checkpoint without target_stats"):
        load_trained(tmp_path / "no_stats.pt")
    wider = TrainConfig(net=NetConfig(width=0.125, fuse_channels=16, fc6=32, fc7=32))
    with pytest.raises(CheckpointError, match=r"good.pt: weights do not fit"):
        load_trained(tmp_path / "good.pt", wider)
