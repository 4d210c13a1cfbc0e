"""Smoke test of bench.edge_speed on a tiny model: its functions build, export and time a run.

No timing is asserted (the machine is shared); what is checked is the bookkeeping: every stage
of a3d-run is accounted for, the stages of a sequential run add up to its frame time, and the
network-alone measurement sees the very inputs a3d-run fed the model.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bench import edge_speed
from tests.test_export import _frames as write_test_frames

pytestmark = pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")
TINY = {
    "net": {"width": 0.125, "fuse_channels": 16, "fc6": 32, "fc7": 32},
    "data": {"input_scale": 0.5},
    "proposals": {"min_area": 20, "max_proposals": 60},
}


@dataclass(frozen=True)
class Tiny:
    checkpoint: Path
    model: Path
    frames: Path  # the first 3 of 4 test frames


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Tiny:
    root = tmp_path_factory.mktemp("edge")
    frames = root / "frames"
    write_test_frames(frames, 4, np.random.default_rng(0))
    checkpoint = edge_speed.random_checkpoint(root / "run" / "checkpoint.pt", "cpu-eighth", TINY)
    model = root / "tiny.onnx"
    edge_speed.export_model(checkpoint, model, frames, threads=1)
    subset = edge_speed.frame_subset(frames, root / "subset", 3)
    assert sorted(p.name for p in subset.glob("*.color.png")) == ["0000.color.png", "0001.color.png",
                                                                  "0002.color.png"]  # fmt: skip
    return Tiny(checkpoint, model, subset)


def test_breakdown_accounts_for_the_whole_frame(tiny: Tiny, tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    run = edge_speed.measure_run(tiny.model, tiny.frames, max_proposals=40, threads=1, rrd=rrd)
    assert run.frames == 3 and 0 < run.rois <= 40 and rrd.stat().st_size > 0
    assert set(run.stages) == set(edge_speed.RUN_STAGES)
    assert all(seconds >= 0 for seconds in run.stages.values())
    assert run.stages["network"] > 0 and run.stages["output"] > 0 and run.stages["rerun"] > 0
    # Sequential: the frame period is the stages plus a little loop overhead (progress bar, generator).
    assert run.stage_sum <= run.frame_seconds * 1.05 + 2e-3
    assert run.frame_seconds <= run.stage_sum * 1.25 + 0.02

    alone = edge_speed.measure_ort(tiny.model, tiny.frames, max_proposals=40, threads=1)
    assert alone.rois == pytest.approx(run.rois)  # the network alone sees a3d-run's inputs
    assert alone.seconds > 0 and alone.one_roi_seconds > 0


def test_a_slow_warm_up_frame_stays_out_of_the_period(tiny: Tiny, monkeypatch: pytest.MonkeyPatch) -> None:
    """The warm-up frame is left out of the stage means, so it must be left out of the period too:
    a stall while a3d-run writes the first line (a cold fsync on a busy disk, the first rerun log)
    once made the period 3 x the stages."""
    fsync, calls = os.fsync, []

    def first_fsync_stalls(fd: int) -> None:
        calls.append(fd)
        if len(calls) == 1:
            time.sleep(0.5)
        fsync(fd)

    monkeypatch.setattr(os, "fsync", first_fsync_stalls)
    run = edge_speed.measure_run(tiny.model, tiny.frames, max_proposals=40, threads=1)
    assert len(calls) == 3
    assert run.frame_seconds <= run.stage_sum * 1.25 + 0.02
