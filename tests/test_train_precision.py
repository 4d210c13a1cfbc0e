"""a3d-train --set solver.precision=bf16: bfloat16 autocast of the forward pass and the loss,
float32 weights; the same run as fp32 up to bfloat16's rounding. A wrong value is one line."""

from __future__ import annotations

import logging

import pytest
import torch

from a3d.train import loop
from a3d.train.checkpoint import load_checkpoint
from a3d.train.cli import main
from a3d.train.loop import read_metrics
from tests.helpers.train_scenes import tiny_train_args, write_scenes


def _train(frames, run, cache, *sets: str) -> int:
    return main(tiny_train_args(frames, run, cache, "solver.iterations=4", "solver.lr_steps=[3]", *sets))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same 4-iteration run in fp32 and in bf16."""
    root = tmp_path_factory.mktemp("precision")
    frames = write_scenes(root / "frames", 2, seed=5)
    for precision in ("fp32", "bf16"):
        assert _train(frames, root / precision, root / "cache", f"solver.precision={precision}") == 0
    return root


def _losses(run) -> list[float]:
    return [r["loss"] for r in read_metrics(run / "metrics.jsonl") if r["kind"] == "train"]


def test_bf16_follows_fp32_up_to_rounding(runs):
    fp32, bf16 = _losses(runs / "fp32"), _losses(runs / "bf16")
    assert len(fp32) == len(bf16) == 4
    # The first loss is the same weights on the same batch: only bfloat16's 8-bit mantissa
    # (relative rounding 2^-9 per operation) separates them, and it does separate them.
    assert fp32[0] != bf16[0]
    assert abs(fp32[0] - bf16[0]) < 0.02 * fp32[0]
    for a, b in zip(fp32, bf16, strict=True):
        assert abs(a - b) < 0.05 * a
    # Weights, gradients and the optimizer stay float32: the checkpoint is an fp32 one, and in
    # row-major layout although a3d-train convolves channels-last.
    weights = load_checkpoint(runs / "bf16" / "checkpoint.pt")["model"]
    floats = [v for v in weights.values() if v.is_floating_point()]
    assert floats and all(v.dtype == torch.float32 for v in floats)
    convs = [v for v in floats if v.dim() == 4 and v.shape[1] > 1 and v.shape[2] > 1]
    assert convs and all(v.is_contiguous() for v in weights.values())


def test_bf16_without_native_instructions_says_it_is_slower(runs, monkeypatch, caplog):
    monkeypatch.setattr(loop, "bf16_instructions", lambda: [])
    with caplog.at_level(logging.WARNING, logger=loop.__name__):
        assert _train(runs / "frames", runs / "emulated", runs / "cache", "solver.precision=bf16",
                      "solver.iterations=1") == 0  # fmt: skip
    assert "no native bfloat16" in caplog.text


def test_unknown_precision_is_one_line(runs, capsys):
    assert _train(runs / "frames", runs / "fp16", runs / "cache", "solver.precision=fp16") == 2
    error = capsys.readouterr().err.strip()
    assert "solver.precision='fp16': expected fp32 or bf16" in error and len(error.splitlines()) == 1, error
    assert not (runs / "fp16" / "checkpoint.pt").exists()
