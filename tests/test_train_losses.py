"""The multi-task loss (known answers, what it ignores) and a tiny overfit run of the training loop."""

from __future__ import annotations

import math

import torch

from a3d.train.config import apply_overrides, load_config
from a3d.train.loop import read_metrics, train
from a3d.train.losses import detection_loss
from tests.helpers.train_scenes import TINY, write_scenes


def _inputs():
    labels = torch.tensor([0, 3, 3, 0])
    logits = torch.zeros(4, 20, requires_grad=True)
    deltas3d = torch.zeros(4, 20 * 7)
    deltas3d[1, 3 * 7 : 3 * 7 + 2] = torch.tensor([0.5, 2.0])  # row 1, class 3: |d| = 0.5 and 2
    deltas3d[2, 3 * 7] = 5.0  # row 2 has no 3D target (weight 0): ignored
    deltas3d[0] = deltas3d[3] = 9.0  # background rows: ignored
    deltas3d.requires_grad_(True)
    deltas2d = torch.zeros(4, 20 * 4)
    deltas2d[2, 3 * 4 + 1] = -3.0  # row 2's 2D target still counts: smooth-L1(3) = 2.5
    deltas2d[0] = 7.0
    deltas2d.requires_grad_(True)
    weights3d = torch.tensor([0.0, 1.0, 0.0, 0.0])
    return dict(
        class_logits=logits, deltas3d=deltas3d, deltas2d=deltas2d, labels=labels,
        targets3d=torch.zeros(4, 7), targets2d=torch.zeros(4, 4), weights3d=weights3d,
    )  # fmt: skip


def test_known_answer_and_what_is_ignored():
    args = _inputs()
    terms = detection_loss(**args, lambda_3d=1.0, lambda_2d=2.0)
    values = terms.as_floats()
    assert math.isclose(values["loss_cls"], math.log(20), rel_tol=1e-6)
    assert math.isclose(values["loss_3d"], (0.5 * 0.5**2 + (2.0 - 0.5)) / 4, rel_tol=1e-6)
    assert math.isclose(values["loss_2d"], 2.5 / 4, rel_tol=1e-6)
    assert math.isclose(values["loss"], math.log(20) + 1.625 / 4 + 2 * 2.5 / 4, rel_tol=1e-6)
    terms.total.backward()
    grad3d = args["deltas3d"].grad.view(4, 20, 7)
    assert grad3d[[0, 2, 3]].abs().sum() == 0  # background and weight-0 rows get no 3D gradient
    assert grad3d[1, 3, :2].tolist() == [0.5 / 4, 1.0 / 4]
    assert grad3d[1].abs().sum() == 1.5 / 4  # the true class's deltas only
    assert args["deltas2d"].grad[[0, 3]].abs().sum() == 0


def test_tiny_run_overfits(tmp_path):
    """Two frames, 40 iterations: the loss falls well below its start (the loop learns)."""
    frames = write_scenes(tmp_path / "frames", 2, seed=4)
    config = apply_overrides(
        load_config("vgg16"),
        [*TINY, "solver.iterations=40", "solver.lr=0.01", "solver.lr_steps=[]", "net.dropout=0.0",
         "data.flip=false", "log.checkpoint_every=1000"],
    )  # fmt: skip
    result = train(frames, tmp_path / "run", config, device="cpu")
    losses = [r["loss"] for r in read_metrics(tmp_path / "run" / "metrics.jsonl") if r["kind"] == "train"]
    assert len(losses) == 40 and result.iteration == 40
    assert sum(losses[-5:]) / 5 < 0.5 * sum(losses[:5]) / 5, losses
    assert (tmp_path / "run" / "loss.png").stat().st_size > 0
