"""a3d.export.read_back: a model file's weights back in torch answer as the file does (BatchNorms
folded, fc6's pooled layout permuted, heads de-normalised); the bundled int8 model reads back."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from a3d.export.onnx_export import RuntimeGraph, export_graph, save_model
from a3d.export.read_back import normalise_heads, read_back
from a3d.export.verify import compare, synthetic_inputs
from a3d.runtime.models import model_path
from a3d.runtime.network.model import DetectorModel
from a3d.train.config import TrainConfig
from a3d.train.dataset import TargetStats
from a3d.train.inference import TorchNetwork
from a3d.train.model import A3DNet, NetConfig
from tests.helpers.runtime_frames import fake_metadata


def _random_stats(rng: np.random.Generator) -> TargetStats:
    return TargetStats(rng.normal(0, 0.3, (20, 7)), rng.uniform(0.1, 1, (20, 7)),
                       rng.normal(0, 0.1, (20, 4)), rng.uniform(0.05, 0.5, (20, 4)))  # fmt: skip


@pytest.mark.slow
def test_a_float_export_reads_back_to_the_network_it_was_made_from(tmp_path: Path) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    config = TrainConfig(net=NetConfig(width=0.125, trunk_norm=True, fuse_channels=16, fc6=32, fc7=32))
    net = A3DNet(config.net)
    with torch.no_grad():  # BatchNorm statistics far from the identity, so that their folding shows
        for module in net.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.running_mean.uniform_(-0.5, 0.5)
                module.running_var.uniform_(0.5, 2.0)
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
    net.eval()
    stats = _random_stats(rng)
    path = tmp_path / "model.onnx"
    graph = export_graph(RuntimeGraph(net, stats), tmp_path / "raw.onnx")
    save_model(graph, fake_metadata(provenance={"training_config": config.to_dict()}), path)

    got = read_back(path, threads=1)
    assert got.layout == "y, x, c" and got.agreement.within(1e-4, 1e-4), got.agreement.describe()
    assert not got.config.net.trunk_norm
    plain = A3DNet(got.config.net)
    other = _random_stats(rng)  # the heads in terms of other statistics answer the same raw deltas
    plain.load_state_dict(normalise_heads(got.weights, other))
    inputs = [synthetic_inputs(0.5, rois=50)]
    same = compare(DetectorModel.load(path, 1), TorchNetwork(plain.eval(), other), inputs)
    assert same.within(1e-4, 1e-4), same.describe()
    original = TorchNetwork(net, stats).run(*dataclasses.astuple(inputs[0])[1:])
    mine = TorchNetwork(plain, other).run(*dataclasses.astuple(inputs[0])[1:])
    for a, b in zip(original, mine, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4 * max(1.0, float(np.abs(a).max())))


def test_the_bundled_int8_model_reads_back_dequantised() -> None:
    got = read_back(model_path("live"), threads=1)
    assert got.layout == "y, c, x"  # a3d.export.refold's
    assert got.agreement.probs.max_abs < 0.5  # int8 rounding; the other layouts answer 0.75 off
    assert got.config.net.width == 0.25 and got.config.net.fc6 == 512
