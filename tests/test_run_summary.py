"""a3d-run's end-of-run summary and its progress lines on a stderr that is not a terminal."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.cli.progress import LineProgress, make_progress
from a3d.runtime.cli.summary import RunSummary
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import class_index

SAMPLES = Path(__file__).resolve().parents[1] / "samples"


def _line(
    classes: list[str], scores: list[float], gravity: str, notes: tuple[str, ...] = ()
) -> FrameDetections:
    n = len(classes)
    ids = np.array([class_index(c) for c in classes], np.int64)
    return FrameDetections(
        "f", np.eye(3), ids, np.array(scores), np.zeros((n, 4)), np.ones((n, 7)), gravity=gravity, notes=notes
    )


def test_summary_counts_what_a_user_should_see() -> None:
    summary = RunSummary(min_score=0.5, started=100.0)
    summary.add(_line(["chair", "chair", "table", "lamp"], [0.9, 0.6, 0.7, 0.2], "estimated"))
    summary.add(
        _line(
            ["chair", "sofa"],
            [0.5, 0.49],
            "fallback: filled depth (raw depth: x)",
            ("proposals capped at 500",),
        )
    )
    summary.add(
        _line([], [], "fallback: camera axes (y)", ("proposals capped at 2000", "depth mostly missing: 97%"))
    )
    summary.fail()
    assert summary.lines(["detections -> d.jsonl", "recording -> r.rrd"], now=102.0) == [
        "4 frames (1 failed) in 2.0 s, 2.00 frames/s",
        "detections scoring >= 0.5 (the viewer's threshold; softmax scores): chair 3, table 1",
        "gravity fallbacks on 2 frames (sources: estimated 1, fallback: camera axes 1, "
        "fallback: filled depth 1); "
        "frames with notes: 'depth mostly missing: N' 1, 'proposals capped at N' 2",
        "outputs: detections -> d.jsonl; recording -> r.rrd",
    ]


def test_progress_lines_every_interval_and_at_the_end() -> None:
    now = [0.0]
    out = io.StringIO()
    progress = LineProgress("a3d-run", 10, out, interval_s=5.0, clock=lambda: now[0])
    for t in (1.0, 2.0, 5.5, 6.0, 9.0, 10.5, 11.0):
        now[0] = t
        progress.update(failed=t == 2.0)
    progress.close()
    assert out.getvalue().splitlines() == [
        "a3d-run: progress: 3 frames of 10, 1 failed, 0.55 frames/s",  # at 5.5 s
        "a3d-run: progress: 6 frames of 10, 1 failed, 0.57 frames/s",  # at 10.5 s
        "a3d-run: progress: 7 frames of 10, 1 failed, 0.64 frames/s",  # the end
    ]
    assert isinstance(make_progress("a3d-run", None, io.StringIO()), LineProgress)  # not a terminal


def test_the_summary_says_when_the_scores_are_calibrated() -> None:
    summary = RunSummary(min_score=0.5, calibrated=True, started=0.0)
    summary.add(_line(["chair"], [0.7], "given"))
    line = summary.lines([], now=1.0)[1]
    assert line == (
        "detections scoring >= 0.5 (the viewer's threshold; "
        "calibrated scores: the chance a detection is right): chair 1"
    )


def test_a3d_run_prints_progress_and_the_summary_when_stderr_is_not_a_terminal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "det.jsonl"
    argv = [
        str(SAMPLES),
        "--output",
        str(out),
        "--headless",
        "--max-proposals",
        "40",
        "--view-min-score",
        "0.5",
    ]
    assert run_cli.main(argv) == 0
    err = capsys.readouterr().err.splitlines()
    assert any(line.startswith("a3d-run: progress: 6 frames of 6, 0 failed, ") for line in err)
    summary = [
        line.removeprefix("a3d-run: summary: ") for line in err if line.startswith("a3d-run: summary: ")
    ]
    assert summary[0].startswith("6 frames (0 failed) in ") and summary[0].endswith(" frames/s")
    # the bundled model carries a score calibration (tests/test_samples.py)
    assert summary[1].startswith(
        "detections scoring >= 0.5 (the viewer's threshold; "
        "calibrated scores: the chance a detection is right): "
    )
    assert summary[2].startswith("gravity fallbacks on 0 frames (sources: given 6)")
    assert summary[3] == f"outputs: detections -> {out}"
    assert err[-1] == f"a3d-run: 6 frames written to {out}, 0 failed"
