"""a3d-run --detector end to end: a 2D detector of each layout adds its boxes to a run, each line
says where every detection's class came from, bad detector inputs are one line and exit 2, and a
frame whose detector fails keeps a3d's own detections and says so."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.postprocess import hold_depth
from a3d.runtime.postprocess.depth_support import sample_depth
from a3d.runtime.postprocess.floor_contact import NO_FLOOR, REACH_M, frame_floor, standing_classes
from a3d.runtime.postprocess.fuse import NETWORK
from a3d.runtime.postprocess.wall_axes import NO_WALLS, SNAP_DEG, wall_direction
from a3d.runtime.sources.folder import FolderSource, write_frame, write_intrinsics
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from tests.helpers.detector_files import (
    INPUT_HW,
    boxes_outputs,
    detector_graph,
    nanodet_outputs,
    yolox_grid,
)
from tests.helpers.runtime_frames import write_scene_folder
from tests.test_run_cli import fake_model, run  # noqa: F401 (fake_model: the fake network's fixture)
from tests.test_wall_axes import K as CORNER_K
from tests.test_wall_axes import room_corner_depth

pytestmark = pytest.mark.usefixtures("fake_model")

EXPECTED = {  # the a3d classes each test file's boxes may take
    "yolox": {"chair", "monitor", "television"},
    "nanodet": {"sofa"},
    "boxes": {"bed", "toilet", "sink"},
}
NAMES = {
    "yolox": ["cat", "chair", "tv"],
    "nanodet": ["chair", "cup", "couch"],
    "boxes": ["bed", "toilet", "sink"],
}


def _detector(folder: Path, layout: str, names: list[str] | None = None) -> Path:
    metadata = {"names": json.dumps(names or NAMES[layout])}
    if layout == "yolox":
        return detector_graph(folder / "yolox.onnx", [1, 3, *INPUT_HW], {"output": yolox_grid()}, metadata)
    if layout == "nanodet":
        return detector_graph(folder / "nanodet.onnx", [1, 3, *INPUT_HW], nanodet_outputs(), metadata)
    return detector_graph(folder / "boxes.onnx", [1, 3, 40, 60], boxes_outputs(), metadata)


@pytest.mark.parametrize("layout", ["yolox", "nanodet", "boxes"])
def test_a_detector_of_each_layout_adds_its_boxes_to_the_run(tmp_path: Path, layout: str) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    detector = _detector(tmp_path, layout)
    plain, joined = tmp_path / "plain.jsonl", tmp_path / "joined.jsonl"
    common = [str(folder), "--headless", "--score-threshold", "0"]
    assert run([*common, "--output", str(plain), "--detector", "none"]) == 0
    assert run([*common, "--output", str(joined), "--detector", str(detector)]) == 0
    for own, both in zip(read_detections(plain), read_detections(joined), strict=True):
        assert own.sources is None  # a run without a detector writes no source
        assert both.sources is not None and set(both.sources) <= {NETWORK, detector.stem,
                                                                   f"{detector.stem}+{NETWORK}"}  # fmt: skip
        from_detector = [i for i, s in enumerate(both.sources) if s.startswith(detector.stem)]
        assert from_detector, f"{layout}: no detection from the detector in frame {both.frame}"
        assert {both.classes[i] for i in from_detector} <= EXPECTED[layout]
        assert np.all(both.boxes3d[from_detector, 3:6] > 0)
        assert len(both) >= len(own) - len(from_detector)  # own detections are kept (or merged)


@pytest.mark.parametrize(
    ("problem", "message"),
    [
        ("layout", "unknown 2D detector layout"),
        ("names", "has 2 class names but the detector"),
        ("class map", "names no a3d class"),
        ("missing", "no such 2D detector file"),
    ],
)
def test_bad_detector_inputs_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture, problem: str, message: str
) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    out = tmp_path / "det.jsonl"
    detector = _detector(tmp_path, "yolox")
    extra = ["--detector", str(detector)]
    if problem == "layout":
        logits = {"logits": np.zeros((1, 10), np.float32)}
        classifier = detector_graph(tmp_path / "cls.onnx", [1, 3, 32, 32], logits)
        extra = ["--detector", str(classifier)]
    elif problem == "names":
        names = tmp_path / "two.names"
        names.write_text("chair\ntv\n")
        extra += ["--detector-names", str(names)]
    elif problem == "class map":
        mapping = tmp_path / "map.json"
        mapping.write_text(json.dumps({"chair": [], "tv": []}))
        extra += ["--class-map", str(mapping)]
    else:
        extra = ["--detector", str(tmp_path / "absent.onnx")]
    assert run([str(folder), "--headless", "--output", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_detector_flags_without_a_detector_are_a_usage_error(tmp_path: Path, capsys) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    names = tmp_path / "x.names"
    names.write_text("chair\n")
    assert run([str(folder), "--headless", "--model", "live", "--detector-names", str(names)]) == 2
    assert "need a 2D detector" in capsys.readouterr().err


def test_a_frame_whose_detector_fails_keeps_its_own_detections_and_says_so(tmp_path: Path) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    # Labels 0..2 with two class names: the third box's class does not exist, found at inference.
    broken = _detector(tmp_path, "boxes", names=["bed", "toilet"])
    plain, joined = tmp_path / "plain.jsonl", tmp_path / "joined.jsonl"
    common = [str(folder), "--headless", "--score-threshold", "0"]
    assert run([*common, "--output", str(plain), "--detector", "none"]) == 0
    assert run([*common, "--output", str(joined), "--detector", str(broken)]) == 0
    (own,), (kept,) = read_detections(plain), read_detections(joined)
    assert kept.scores.tolist() == own.scores.tolist() and set(kept.sources) == {NETWORK}
    (note,) = [n for n in kept.notes if "2D detector" in n]
    assert note.startswith("2D detector boxes failed (ValueError: ") and "a3d's own detections only" in note


def test_with_a_detector_boxes_are_squared_to_the_walls_and_set_on_the_floor_or_the_line_says_none(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The pipeline's wall and floor steps (postprocess.wall_axes, floor_contact) run where the
    detector's boxes joined: in a room corner's frame every yaw within SNAP_DEG of its wall
    direction lies on it, and every box of a standing class ends on the floor or further from it
    than REACH_M; a frame whose depth shows no walls or floor says so; a run without a detector
    does neither. (Step 9, which grows boxes after them, is off here: tests/test_hold_depth.py.)"""
    monkeypatch.setattr(hold_depth, "MARGIN_M", 0.0)
    folder = write_scene_folder(tmp_path / "frames", ["a"])  # too small a frame for any wall
    corner = tmp_path / "corner"
    write_intrinsics(corner, CORNER_K)
    R_tilt = rtilt_from_pitch_roll(np.radians(-10.0), 0.0)
    depth = room_corner_depth(17.0, R_tilt)
    write_frame(corner, "c", np.full((*depth.shape, 3), 128, np.uint8), depth, R_tilt=R_tilt)
    detector = str(_detector(tmp_path, "yolox"))
    for frames, walls in ((folder, False), (corner, True)):
        plain, joined = tmp_path / f"{frames.name}_plain.jsonl", tmp_path / f"{frames.name}_joined.jsonl"
        common = [str(frames), "--headless", "--score-threshold", "0"]
        assert run([*common, "--output", str(plain), "--detector", "none"]) == 0
        assert run([*common, "--output", str(joined), "--detector", detector]) == 0
        ((own,), (line,)) = read_detections(plain), read_detections(joined)
        assert NO_WALLS not in own.notes and (NO_WALLS in line.notes) != walls
        assert NO_FLOOR not in own.notes and (NO_FLOOR in line.notes) != walls
        if walls:
            (loader,) = FolderSource(corner)  # the depth as the run read it (millimetres)
            frame = loader.load()
            plane = frame_floor(sample_depth(frame.depth, frame.intrinsics, line.R_tilt))
            standing = standing_classes()[line.class_ids]
            centres = line.boxes3d[standing, :3] @ line.R_tilt.T  # tilt frame
            floor = centres[:, 0] * plane[0] + centres[:, 2] * plane[1] + plane[2]
            gap = np.abs(floor - centres[:, 1] - line.boxes3d[standing, 5] / 2)
            assert (gap < 1e-4).any(), "no standing box set on the floor"
            assert ((gap < 1e-4) | (gap > REACH_M)).all()  # the file keeps a micrometre
            direction = wall_direction(frame.depth, frame.intrinsics, line.R_tilt)
            assert direction is not None and np.degrees(direction) == pytest.approx(17.0, abs=0.5)
            off = np.degrees((line.boxes3d[:, 6] - direction + np.pi / 4) % (np.pi / 2) - np.pi / 4)
            near = np.abs(off) <= SNAP_DEG + 1e-3
            assert near.any(), "no yaw near the walls to square"
            np.testing.assert_allclose(off[near], 0.0, atol=1e-3)  # the file keeps 1e-6 of a radian
