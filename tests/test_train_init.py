"""a3d-train --set solver.init=CHECKPOINT: a fine-tuned run starts from another run's weights and
keeps that run's regression targets; its errors are one line."""

from __future__ import annotations

import pytest
import torch

from a3d.train.checkpoint import load_checkpoint
from a3d.train.cli import main
from tests.helpers.train_scenes import TINY, write_scenes


def _train(frames, run, cache, *sets: str) -> int:
    args = [*TINY, "solver.iterations=3", "solver.lr_steps=[2]", f"data.cache_dir={cache}", *sets]
    return main([str(frames), "--out", str(run), "--config", "vgg16", "--device", "cpu",
                 *[a for s in args for a in ("--set", s)]])  # fmt: skip


def _is_running_statistic(name: str) -> bool:
    return name.rsplit(".", 1)[-1] in ("running_mean", "running_var", "num_batches_tracked")


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A 3-iteration run on one set of scenes: the checkpoint to fine-tune."""
    root = tmp_path_factory.mktemp("init")
    frames = write_scenes(root / "frames_a", 2, seed=3)
    assert _train(frames, root / "a", root / "cache") == 0
    return root, load_checkpoint(root / "a" / "checkpoint.pt")


def test_fine_tuned_run_starts_from_the_weights_and_keeps_the_targets(source):
    root, trained = source
    other = write_scenes(root / "frames_b", 2, seed=8)  # other scenes: other target statistics
    init = f"solver.init={root / 'a' / 'checkpoint.pt'}"
    # At lr 0 SGD moves no weight (batch norm's running statistics still follow the new scenes),
    # so the fine-tuned run ends with the weights it started from.
    assert _train(other, root / "b", root / "cache", init, "solver.lr=0") == 0
    tuned = load_checkpoint(root / "b" / "checkpoint.pt")
    assert tuned["iteration"] == 3
    weights = {n: v for n, v in trained["model"].items() if not _is_running_statistic(n)}
    assert len(weights) > 10
    for name, value in weights.items():
        assert torch.equal(tuned["model"][name], value), name
    assert torch.equal(tuned["mean_sizes"], trained["mean_sizes"])
    for name, value in trained["target_stats"].items():
        assert torch.equal(tuned["target_stats"][name], value), name

    # The same run from scratch: other weights and other statistics, so the two checks above could fail.
    assert _train(other, root / "c", root / "cache", "solver.lr=0") == 0
    scratch = load_checkpoint(root / "c" / "checkpoint.pt")
    assert any(not torch.equal(scratch["model"][n], v) for n, v in weights.items())
    assert any(not torch.equal(scratch["target_stats"][n], v) for n, v in trained["target_stats"].items())


def test_init_errors_are_one_line(source, capsys):
    root, _ = source
    frames = root / "frames_a"
    checkpoint = root / "a" / "checkpoint.pt"
    cases = [
        ((f"solver.init={root / 'missing.pt'}",), "missing.pt: no such checkpoint file"),
        ((f"solver.init={checkpoint}", "net.fc6=48"), "weights do not fit the network config"),
        ((f"solver.init={checkpoint}", f"solver.pretrained={checkpoint}"),
         "solver.init and solver.pretrained are both set"),
    ]  # fmt: skip
    for i, (sets, expected) in enumerate(cases):
        assert _train(frames, root / f"bad{i}", root / "cache", *sets) == 2
        error = capsys.readouterr().err.strip()
        assert expected in error and len(error.splitlines()) == 1, error
        assert not (root / f"bad{i}" / "checkpoint.pt").exists()


def test_resume_with_another_network_is_one_line(source, capsys):
    """--resume --set net.*: the run's own weights do not fit; one line, and the checkpoint is kept."""
    root, _ = source
    run = root / "a"
    before = (run / "checkpoint.pt").read_bytes()
    args = [str(root / "frames_a"), "--out", str(run), "--resume", "--iters", "4", "--set", "net.fc6=48"]
    assert main(args) == 2
    error = capsys.readouterr().err.strip()
    assert "checkpoint.pt" in error and "weights do not fit the network config" in error, error
    assert len(error.splitlines()) == 1, error
    assert (run / "checkpoint.pt").read_bytes() == before
