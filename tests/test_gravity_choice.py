"""The gravity a frame uses and where it came from: the documented fallback order, and that a
fallback is reported (in the detections line and as one stderr warning per frame)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.gravity import GRAVITY_ESTIMATED, GRAVITY_GIVEN, choose_gravity
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS as K
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from tests.helpers.samples import SAMPLE_MODEL
from tests.test_gravity import CORNER, ROOM, angle_deg, render

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
TRUTH = rtilt_from_pitch_roll(np.radians(-12.0), np.radians(4.0))


def _choose(depth: np.ndarray, given: np.ndarray | None = None):
    return choose_gravity(depth, fill_depth(depth), K, given)


def test_given_r_tilt_is_used_as_given() -> None:
    choice = _choose(render(TRUTH, ROOM), given=TRUTH @ rtilt_from_pitch_roll(0.1, 0.0))
    assert choice.source == GRAVITY_GIVEN and not choice.is_fallback
    assert angle_deg(choice.R_tilt, TRUTH) > 5.0  # the given one, not the estimate


def test_dense_depth_is_estimated() -> None:
    choice = _choose(render(TRUTH, ROOM, noise=0.003))
    assert choice.source == GRAVITY_ESTIMATED
    assert angle_deg(choice.R_tilt, TRUTH) < 1.0


@pytest.mark.parametrize("holes", [0.9, 0.97])
def test_sparse_depth_falls_back_to_the_filled_depth_and_says_why(holes: float) -> None:
    choice = _choose(render(TRUTH, ROOM, noise=0.003, holes=holes))
    assert choice.source.startswith("fallback: filled depth (raw depth: too few surface normals")
    assert angle_deg(choice.R_tilt, TRUTH) < 2.0


def test_no_floor_anywhere_falls_back_to_the_walls() -> None:
    choice = _choose(render(TRUTH, CORNER, noise=0.003))
    assert choice.source.startswith("fallback: walls only (raw depth: no floor-like surface")
    assert angle_deg(choice.R_tilt, TRUTH) < 2.0


def test_no_depth_falls_back_to_the_camera_axes() -> None:
    choice = _choose(np.zeros((120, 160), np.float32))
    assert choice.source == (
        "fallback: camera axes (raw depth: too few surface normals; filled depth: too few surface normals)"
    )
    np.testing.assert_array_equal(choice.R_tilt, np.eye(3))


def test_a3d_run_reports_a_gravity_fallback_in_the_line_and_once_on_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A sample frame without its R_tilt and with 90 % of its depth dropped: the line names the
    fallback and stderr carries exactly one warning for the frame; the intact frame says estimated."""
    folder = tmp_path / "frames"
    folder.mkdir()
    shutil.copy(SAMPLES / "intrinsics.json", folder)
    for name in ("synth_000000", "synth_000001"):
        shutil.copy(SAMPLES / f"{name}.color.png", folder)
        depth = cv2.imread(str(SAMPLES / f"{name}.depth.png"), cv2.IMREAD_UNCHANGED)
        if name == "synth_000001":
            depth[np.random.default_rng(0).random(depth.shape) < 0.9] = 0
        cv2.imwrite(str(folder / f"{name}.depth.png"), depth)
    out = tmp_path / "det.jsonl"
    argv = [str(folder), "--model", str(SAMPLE_MODEL), "--output", str(out), "--headless"]
    assert run_cli.main([*argv, "--max-proposals", "50"]) == 0
    lines = {d["frame"]: d for d in map(json.loads, out.read_text().splitlines())}
    assert lines["synth_000000"]["gravity"] == GRAVITY_ESTIMATED
    assert lines["synth_000001"]["gravity"].startswith("fallback: filled depth (raw depth: too few")
    assert "depth mostly missing: 9" in " ".join(lines["synth_000001"]["notes"])
    err = capsys.readouterr().err.splitlines()
    warnings = [line for line in err if line.startswith("a3d-run: warning: ") and "gravity fallback" in line]
    assert len(warnings) == 1 and "synth_000001" in warnings[0]
