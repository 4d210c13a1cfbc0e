"""a3d-train killed with SIGKILL mid-run and resumed ends bit-identical to an uninterrupted run."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from a3d.train.checkpoint import load_checkpoint
from a3d.train.cli import config_source, main
from a3d.train.loop import read_metrics
from tests.helpers.train_scenes import tiny_train_args, write_scenes

ITERATIONS = 12


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "a3d.train.cli", *args]


def _args(frames, run, cache, workers: int = 1) -> list[str]:
    return tiny_train_args(frames, run, cache, f"solver.iterations={ITERATIONS}", "solver.lr_steps=[7]",
                           "log.checkpoint_every=3", f"data.workers={workers}")  # fmt: skip


def _last_iter(run) -> int:
    return max((r["iter"] for r in read_metrics(run / "metrics.jsonl") if r["kind"] == "train"), default=0)


@pytest.mark.slow  # three training processes, one killed
def test_kill_and_resume_is_bit_identical(tmp_path):
    frames = write_scenes(tmp_path / "frames", 3, seed=6)
    cache = tmp_path / "cache"
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    # The uninterrupted run loads its data in-process: worker processes must not change a bit either.
    done = subprocess.run(_cli(*_args(frames, straight, cache, workers=0)), capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"a3d-export {straight / 'checkpoint.pt'} -o {straight / 'model.onnx'}"

    # Same run, SIGKILLed (with its DataLoader worker) once it is past the checkpoint at iteration 3.
    proc = subprocess.Popen(_cli(*_args(frames, killed, cache)), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while _last_iter(killed) < 5 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    interrupted_at = load_checkpoint(killed / "checkpoint.pt")["iteration"]
    assert 3 <= interrupted_at < ITERATIONS

    resumed = subprocess.run(_cli(str(frames), "--out", str(killed), "--resume", "--device", "cpu"),
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    a, b = load_checkpoint(straight / "checkpoint.pt"), load_checkpoint(killed / "checkpoint.pt")
    assert a["iteration"] == b["iteration"] == ITERATIONS
    assert a["model"].keys() == b["model"].keys()
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    momentum = [(s["momentum_buffer"], b["optimizer"]["state"][i]["momentum_buffer"])
                for i, s in a["optimizer"]["state"].items()]  # fmt: skip
    assert momentum and all(torch.equal(x, y) for x, y in momentum)
    # The metrics log holds every iteration once, and the same losses as the straight run.
    lines = {r["iter"]: r["loss"] for r in read_metrics(straight / "metrics.jsonl") if r["kind"] == "train"}
    again = [(r["iter"], r["loss"]) for r in read_metrics(killed / "metrics.jsonl") if r["kind"] == "train"]
    assert [i for i, _ in again] == list(range(1, ITERATIONS + 1))
    assert all(lines[i] == loss for i, loss in again)

    # Ctrl-C (SIGINT) instead: the run finishes its iteration, saves it as a checkpoint and exits 130;
    # --resume continues from that iteration, not from the last periodic checkpoint.
    stopped = tmp_path / "stopped"
    proc = subprocess.Popen(_cli(*_args(frames, stopped, cache)), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while _last_iter(stopped) < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    seen = _last_iter(stopped)
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, err
    saved = load_checkpoint(stopped / "checkpoint.pt")["iteration"]
    assert seen <= saved < ITERATIONS and _last_iter(stopped) == saved
    assert f"checkpoint of iteration {saved} saved" in err and "Traceback" not in err
    resumed = subprocess.run(_cli(str(frames), "--out", str(stopped), "--resume", "--device", "cpu"),
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    c = load_checkpoint(stopped / "checkpoint.pt")
    assert c["iteration"] == ITERATIONS and all(torch.equal(a["model"][k], c["model"][k]) for k in a["model"])


def test_resume_and_overwrite_errors_are_one_line(tmp_path, capsys):
    frames = write_scenes(tmp_path / "frames", 1)
    assert main([str(frames), "--out", str(tmp_path / "nothing"), "--resume"]) == 2
    assert capsys.readouterr().err.strip().endswith("checkpoint.pt: no such checkpoint file")
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"not a checkpoint")
    assert main(_args(frames, run, tmp_path / "cache")) == 2
    assert "a run exists here" in capsys.readouterr().err
    metrics_only = tmp_path / "metrics-only"  # interrupted before its first checkpoint: still a run
    metrics_only.mkdir()
    (metrics_only / "metrics.jsonl").write_text("")
    assert main(_args(frames, metrics_only, tmp_path / "cache")) == 2
    assert "--force" in capsys.readouterr().err
    assert main([*_args(frames, metrics_only, tmp_path / "cache"), "--force", "--iters", "2"]) == 0
    assert load_checkpoint(metrics_only / "checkpoint.pt")["iteration"] == 2
    with pytest.raises(SystemExit):
        main([*_args(frames, run, tmp_path / "cache"), "--force", "--resume"])
    capsys.readouterr()
    assert main([str(frames), "--out", str(run), "--resume"]) == 2
    error = capsys.readouterr().err.strip()
    assert "corrupted, truncated or not a checkpoint" in error and len(error.splitlines()) == 1
    assert main([str(frames), "--out", str(tmp_path / "x"), "--set", "solver.lr=fast"]) == 2
    assert "solver.lr must be a finite number" in capsys.readouterr().err


def test_default_preset_follows_the_device(capsys) -> None:
    args = argparse.Namespace(config=None, device="cpu")
    assert config_source(args) == "cpu-small"
    assert capsys.readouterr().err.strip() == (
        "a3d-train: no --config: preset cpu-small (no CUDA device; --config picks another)"
    )
    assert config_source(argparse.Namespace(config="vgg16", device="cpu")) == "vgg16"
    assert capsys.readouterr().err == ""
