"""Smoke test of bench/edge_speed.py on a tiny model: its functions build, export and time a run.

No timing is asserted (the machine is shared); what is checked is the bookkeeping: every stage
of a3d-run is accounted for, the stages of a sequential run add up to its frame time, and the
network-alone measurement sees the very inputs a3d-run fed the model.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from tests.helpers.synth_frames import write_synth_frames

# slow: an ONNX export and timed a3d-run processes
pytestmark = [
    pytest.mark.slow,
    pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning"),
]
BENCH = Path(__file__).resolve().parents[1] / "bench" / "edge_speed.py"
TINY = {
    "net": {"width": 0.125, "fuse_channels": 16, "fc6": 32, "fc7": 32},
    "data": {"input_scale": 0.5},
    "proposals": {"min_area": 20, "max_proposals": 60},
}


@pytest.fixture(scope="module")
def edge_speed():
    spec = importlib.util.spec_from_file_location("edge_speed", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["edge_speed"] = module  # dataclasses resolve their module by name
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("edge_speed", None)


def test_breakdown_accounts_for_the_whole_frame(edge_speed, tmp_path: Path) -> None:
    frames = write_synth_frames(tmp_path / "synth", 4)
    checkpoint = edge_speed.random_checkpoint(tmp_path / "run" / "checkpoint.pt", "cpu-eighth", TINY)
    model = tmp_path / "tiny.onnx"
    edge_speed.export_model(checkpoint, model, frames, threads=1)
    subset = edge_speed.frame_subset(frames, tmp_path / "subset", 3)
    names = sorted(p.name for p in subset.glob("*.color.png"))
    assert names == [f"synth_00000{i}.color.png" for i in range(3)]

    rrd = tmp_path / "run.rrd"
    run = edge_speed.measure_run(model, subset, max_proposals=40, threads=1, rrd=rrd)
    assert run.frames == 3 and 0 < run.rois <= 40 and rrd.stat().st_size > 0
    assert set(run.stages) == set(edge_speed.RUN_STAGES)
    assert all(seconds >= 0 for seconds in run.stages.values())
    assert run.stages["network"] > 0 and run.stages["output"] > 0 and run.stages["rerun"] > 0
    # Sequential: the frame period is the stages plus a little loop overhead (progress bar, generator).
    assert run.stage_sum <= run.frame_seconds * 1.05 + 2e-3
    assert run.frame_seconds <= run.stage_sum * 1.25 + 0.02

    alone = edge_speed.measure_ort(model, subset, max_proposals=40, threads=1)
    assert alone.rois == pytest.approx(run.rois)  # the network alone sees a3d-run's inputs
    assert alone.seconds > 0 and alone.one_roi_seconds > 0
