"""a3d-eval's gravity report: the angle between each line's gravity and the ground truth's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli.eval import load_truth, main
from a3d.runtime.evaluation.gravity_report import gravity_report
from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
TILTS_DEG = [0.0, 1.0, 2.0, 3.0, 4.0, 20.0]  # one per sample frame, in name order


def _lines(truth: dict) -> list[FrameDetections]:
    """Empty lines whose R_tilt is the truth's with an extra pitch of TILTS_DEG."""
    lines = []
    for (name, t), tilt, source in zip(
        sorted(truth.items()),
        TILTS_DEG,
        ["estimated"] * 4 + ["fallback: filled depth (x)", None],
        strict=True,
    ):
        R = rtilt_from_pitch_roll(np.radians(tilt), 0.0) @ t.R_tilt
        empty = (np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 4)), np.zeros((0, 7)))
        lines.append(FrameDetections(name, R, *empty, gravity=source))
    return lines


def test_report_angles_and_sources() -> None:
    truth, _ = load_truth(SAMPLES)
    report = gravity_report(truth, {d.frame: d for d in _lines(truth)})
    np.testing.assert_allclose(report.angles_deg, TILTS_DEG, atol=1e-6)
    s = report.summary()
    assert s["frames"] == 6 and s["median_deg"] == pytest.approx(2.5) and s["max_deg"] == pytest.approx(20.0)
    assert s["p95_deg"] == pytest.approx(np.percentile(TILTS_DEG, 95))
    assert s["sources"] == {"estimated": 4, "fallback: filled depth": 1, "unknown": 1}


def test_a3d_eval_prints_and_writes_the_gravity_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, _ = load_truth(SAMPLES)
    write_detections(tmp_path / "det.jsonl", _lines(truth))
    assert main([str(SAMPLES), "--detections", str(tmp_path / "det.jsonl"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (
        "gravity vs ground truth (6 frames; not seen by the mAP): angle median 2.50, p95 16.00, max 20.00"
        in out
    )
    written = json.loads((tmp_path / "eval.json").read_text())["inputs"]["gravity"]
    assert written["max_deg"] == pytest.approx(20.0)
