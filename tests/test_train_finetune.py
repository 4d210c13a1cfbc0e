"""a3d-train --set solver.init=CHECKPOINT: a fine-tuned run starts from another run's weights and
keeps that run's regression targets; a3d-average takes the mean of such runs. Errors are one line."""

from __future__ import annotations

import json

import pytest
import torch

from a3d.export.metadata import provenance
from a3d.train.average_cli import main as average
from a3d.train.checkpoint import checkpoint_config, load_checkpoint, load_trained
from a3d.train.cli import main
from tests.helpers.train_scenes import tiny_train_args, write_scenes


def _train(frames, run, cache, *sets: str) -> int:
    return main(tiny_train_args(frames, run, cache, "solver.iterations=3", "solver.lr_steps=[2]", *sets))


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


def test_average_of_fine_tuned_runs_is_their_mean(source, capsys):
    root, trained = source
    init = f"solver.init={root / 'a' / 'checkpoint.pt'}"
    runs = [root / f"seed{seed}" for seed in (1, 2)]
    for seed, run in zip((1, 2), runs, strict=True):
        assert (
            _train(root / "frames_a", run, root / "cache", init, f"solver.seed={seed}", "solver.lr=0.01") == 0
        )
    a, b = (load_checkpoint(run / "checkpoint.pt") for run in runs)
    soup_path = root / "soup.pt"
    assert average([str(run / "checkpoint.pt") for run in runs] + ["--out", str(soup_path)]) == 0
    assert "2 checkpoints averaged" in capsys.readouterr().err
    soup = load_checkpoint(soup_path)
    moved = [
        n
        for n in a["model"]
        if a["model"][n].is_floating_point() and not torch.equal(a["model"][n], b["model"][n])
    ]
    assert len(moved) > 10  # the two seeds differ, so the mean is neither run
    for name in moved:
        assert torch.allclose(soup["model"][name], (a["model"][name] + b["model"][name]) / 2, atol=1e-7), name
        assert not torch.equal(soup["model"][name], a["model"][name]), name
    for name, value in trained["target_stats"].items():
        assert torch.equal(soup["target_stats"][name], value), name
    assert "optimizer" not in soup and soup["iteration"] == 3
    sources = [entry["path"] for entry in soup["averaged"]]
    assert sources == [str((run / "checkpoint.pt").resolve()) for run in runs]

    # The soup exports like a run: its network loads, and its provenance names the sources.
    net = load_trained(soup_path).net
    assert torch.equal(net.state_dict()[moved[0]], soup["model"][moved[0]])
    origin = provenance(soup, checkpoint_config(soup_path, soup), soup_path, {})
    assert [entry["sha256"] for entry in origin["checkpoint"]["averaged"]] == [
        e["sha256"] for e in soup["averaged"]
    ]

    # It fine-tunes further (solver.init), but it holds no optimizer state to resume.
    (root / "soup-run").mkdir()
    (root / "soup-run" / "checkpoint.pt").write_bytes(soup_path.read_bytes())
    assert main([str(root / "frames_a"), "--out", str(root / "soup-run"), "--resume"]) == 2
    error = capsys.readouterr().err.strip()
    assert "no optimizer state to resume" in error and len(error.splitlines()) == 1, error


def test_average_errors_are_one_line(source, capsys):
    root, _ = source
    checkpoint = root / "a" / "checkpoint.pt"
    assert _train(root / "frames_a", root / "narrow", root / "cache", "net.fc6=48") == 0
    other = write_scenes(root / "frames_c", 2, seed=11)  # other scenes: other regression targets
    assert _train(other, root / "other", root / "cache") == 0
    capsys.readouterr()
    cases = [
        ([checkpoint], "two or more checkpoints, got 1"),
        ([checkpoint, root / "missing.pt"], "missing.pt: no such checkpoint file"),
        ([checkpoint, root / "narrow" / "checkpoint.pt"], "another network config"),
        ([checkpoint, root / "other" / "checkpoint.pt"], "other regression targets"),
    ]
    for paths, expected in cases:
        assert average([*map(str, paths), "--out", str(root / "bad.pt")]) == 2
        error = capsys.readouterr().err.strip()
        assert expected in error and len(error.splitlines()) == 1, error
        assert not (root / "bad.pt").exists()
    with pytest.raises(SystemExit):
        average([str(checkpoint), str(checkpoint), "--out", str(checkpoint)])
    assert "is one of the checkpoints" in capsys.readouterr().err


def test_fine_tuning_on_two_folders(source):
    """Your camera's frames beside the synthetic ones: a3d-train takes several folders."""
    root, _ = source
    mine = write_scenes(root / "mine", 1, seed=21)
    init = f"solver.init={root / 'a' / 'checkpoint.pt'}"
    sets = ("solver.iterations=2", "solver.lr_steps=[1]")
    assert _train([root / "frames_a", mine], root / "both", root / "cache", *sets, init) == 0
    lines = [json.loads(line) for line in (root / "both" / "metrics.jsonl").read_text().splitlines()]
    data = next(line for line in lines if line["kind"] == "data")
    assert data["frames"] + data["skipped"] == 3  # two frames of frames_a, one of mine
