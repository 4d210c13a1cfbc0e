"""Shared fixtures: one tiny exported model for the tests that run a3d-run as a user would."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real a3d-export graph (A3DNet at width 0.125, random weights) with the runtime tests' fake
    metadata (tests/helpers/runtime_frames.py: half-scale input, 60 proposals): ~10 s to export,
    once per session."""
    pytest.importorskip("torch")
    import torch

    from a3d.export.onnx_export import RuntimeGraph, export_graph, save_model
    from a3d.train.dataset import TargetStats
    from a3d.train.model import A3DNet, NetConfig
    from tests.helpers.runtime_frames import fake_metadata

    torch.manual_seed(0)
    net = A3DNet(NetConfig(width=0.125, fc6=32, fc7=32, dropout=0.0)).eval()
    root = tmp_path_factory.mktemp("tiny_model")
    raw = export_graph(RuntimeGraph(net, TargetStats.identity()), root / "raw.onnx")
    path = root / "model.onnx"
    save_model(raw, fake_metadata(), path)
    return path


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that needs the exported tiny model is slow (the export takes 10-60 s on 2 cores)."""
    for item in items:
        if "tiny_model" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)
