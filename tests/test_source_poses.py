"""Camera poses into frames: the frame folder's meta.json, TUM's groundtruth.txt, 7-Scenes folders,
the Python API and the detections line; a bad or missing pose costs the frame its pose only, and
its line and stderr say so."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime import Detector
from a3d.runtime.cli import run as run_cli
from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import format_line, parse_line, read_detections
from a3d.runtime.mapping.world import down_of_up_axis, rtilt_from_pose
from a3d.runtime.pipeline import PipelineConfig
from a3d.runtime.sources.arrays import ArrayError
from a3d.runtime.sources.folder import write_frame
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.runtime.sources.seven_scenes import SevenScenesSource
from a3d.runtime.structures.pose import make_pose
from tests.helpers.runtime_frames import FakeModel, K, scene, write_scene_folder
from tests.real_formats import synth_frames, write_seven_scenes, write_tum, write_tum_trajectory


def pose_of(i: float) -> np.ndarray:
    a = 0.2 + 0.1 * i
    R = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    return make_pose(R, [0.5 * i, -1.4, 2.0 - 0.1 * i])


@pytest.fixture
def fake_model(monkeypatch: pytest.MonkeyPatch) -> FakeModel:
    model = FakeModel()
    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: model)
    return model


def run_lines(source: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> tuple[int, list[dict], str]:
    out = tmp_path / "det.jsonl"
    code = run_cli.main([str(source), "--model", "fake.onnx", "--output", str(out), "--headless"])
    return code, [json.loads(line) for line in out.read_text().splitlines()], capsys.readouterr().err


def test_frame_folder_pose_round_trips_and_a_bad_one_costs_only_the_pose(
    tmp_path: Path, fake_model: FakeModel, capsys: pytest.CaptureFixture
) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    color, depth = scene(0)
    write_frame(folder, "a", color, depth, pose=pose_of(1))
    meta = folder / "b.meta.json"
    document = json.loads(meta.read_text())
    document["pose"] = (pose_of(2) @ np.diag([1.0, 1.0, -1.0, 1.0])).tolist()  # a reflection
    meta.write_text(json.dumps(document))
    frames = {loader.name: loader.load() for loader in open_source(folder, SourceOptions())}
    np.testing.assert_allclose(frames["a"].pose, pose_of(1), atol=1e-15)
    assert frames["b"].pose is None and frames["b"].R_tilt is not None  # the rest of the meta is read
    assert (
        frames["b"].pose_note
        == f"no pose: {meta}: pose: not a rigid transform: det R = -1 (a reflection, not a rotation)"
    )
    with pytest.raises(ValueError, match="pose: not a rigid transform"):
        write_frame(folder, "c", color, depth, pose=pose_of(1) * [[2], [2], [2], [1]])

    code, lines, err = run_lines(folder, tmp_path, capsys)
    assert code == 0
    np.testing.assert_array_equal(lines[0]["pose"], frames["a"].pose)
    assert not any("pose" in note for note in lines[0].get("notes", []))
    assert "pose" not in lines[1] and lines[1]["notes"][0] == frames["b"].pose_note
    assert f"a3d-run: warning: {meta}: pose: not a rigid transform" in err
    assert "(the frame is processed without a pose)" in err


def test_tum_groundtruth_gives_each_frame_its_interpolated_pose(
    tmp_path: Path, fake_model: FakeModel, capsys: pytest.CaptureFixture
) -> None:
    stamps = [100.0, 100.1, 100.2]
    folder = tmp_path / "rgbd_dataset_freiburg1_desk"
    write_tum(folder, synth_frames((3, 4, 5)), stamps)
    # poses at 100.08 and 100.12 around the second frame; the first frame is before the trajectory
    # starts, the third in a 0.2 s gap
    write_tum_trajectory(folder, [100.08, 100.12, 100.32], [pose_of(0), pose_of(2), pose_of(4)])
    frames = [loader.load() for loader in open_source(folder, SourceOptions())]
    np.testing.assert_allclose(frames[1].pose, pose_of(1), atol=1e-6)  # halfway, in angle and position
    assert frames[0].pose is None and frames[0].pose_note == (
        "no pose: time 100.000000 is outside groundtruth.txt's span [100.080000, 100.320000]"
    )
    assert frames[2].pose is None and "0.200 s apart (more than 0.05 s)" in frames[2].pose_note
    wider = open_source(folder, SourceOptions(extra={"max_pose_gap": 0.25}))
    np.testing.assert_allclose(list(wider)[2].load().pose, pose_of(2.8), atol=1e-6)  # 0.4 of the way

    code, lines, err = run_lines(folder, tmp_path, capsys)
    assert code == 0 and [("pose" in line) for line in lines] == [False, True, False]
    assert lines[0]["notes"][0] == frames[0].pose_note
    warnings = [line for line in err.splitlines() if line.startswith("a3d-run: warning: ")]
    assert sum("no pose: " in line for line in warnings) == 2


def test_tum_without_groundtruth_has_no_poses_and_no_notes(tmp_path: Path) -> None:
    folder = tmp_path / "rgbd_dataset_freiburg1_desk"
    write_tum(folder, synth_frames((3,)), [100.0])
    source = open_source(folder, SourceOptions())
    frame = next(iter(source)).load()
    assert not source.has_poses and frame.pose is None and frame.pose_note == ""


def test_seven_scenes_folder_is_recognised_with_poses_intrinsics_and_missing_depth(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    synth = synth_frames((3, 4, 5))
    folder = tmp_path / "seq-01"
    depths = write_seven_scenes(folder, synth, [pose_of(i) for i in range(3)])
    (folder / "frame-000001.pose.txt").unlink()
    (folder / "frame-000002.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    source = open_source(folder, SourceOptions())
    assert isinstance(source, SevenScenesSource) and source.incomplete == []
    with caplog.at_level("WARNING"):
        frames = [loader.load() for loader in source]
    assert [f.name for f in frames] == ["frame-000000", "frame-000001", "frame-000002"]
    assert frames[0].intrinsics.fx == pytest.approx(synth[0].intrinsics.fx, abs=1e-6)
    for frame, depth in zip(frames, depths, strict=True):
        np.testing.assert_array_equal(frame.depth, depth)  # 65535 read as missing
    assert (frames[0].depth == 0).any()
    np.testing.assert_allclose(frames[0].pose, pose_of(0), atol=1e-8)
    assert (
        frames[1].pose is None
        and frames[1].pose_note == f"no pose: {folder / 'frame-000001.pose.txt'}: missing"
    )
    assert frames[2].pose_note == (
        f"no pose: {folder / 'frame-000002.pose.txt'}: expected a 4x4 pose (16 numbers), "
        "got '1 0 0 0\\n0 1 0 0\\n0 0 1 0'"
    )
    assert caplog.text.count("(the frame is processed without a pose)") == 2

    (folder / "camera-intrinsics.txt").write_text("500 0 60\n0 500 40\n")
    with pytest.raises(
        InputError, match=r"camera-intrinsics.txt: expected a 3x3 camera matrix \(9 numbers\)"
    ):
        open_source(folder, SourceOptions())
    given = SourceOptions(intrinsics=K)
    assert next(iter(open_source(folder, given))).load().intrinsics == K  # --intrinsics replaces the file


def test_python_api_takes_a_pose_and_the_line_carries_it(tmp_path: Path) -> None:
    model = FakeModel()
    detector = Detector(model, PipelineConfig.from_metadata(model.metadata))
    color, depth = scene(1)
    result = detector.detect(color[..., ::-1].copy(), depth, K, pose=pose_of(3))
    np.testing.assert_array_equal(result.pose, pose_of(3))
    again = parse_line(result.to_json(), "line")
    np.testing.assert_array_equal(again.pose, pose_of(3))
    assert detector.detect(color[..., ::-1].copy(), depth, K).pose is None
    with pytest.raises(ArrayError, match=r"^pose: not a rigid transform: .* not orthonormal"):
        detector.detect(color[..., ::-1].copy(), depth, K, pose=pose_of(3) * [[1.5], [1.5], [1.5], [1]])

    bad = json.loads(format_line(result))
    bad["pose"][0][0] = 3.0
    path = tmp_path / "det.jsonl"
    path.write_text(json.dumps(bad) + "\n")
    with pytest.raises(InputError, match=rf"^{path}:1: pose: not a rigid transform"):
        read_detections(path)


def test_world_up_takes_gravity_from_the_poses(
    tmp_path: Path, fake_model: FakeModel, capsys: pytest.CaptureFixture
) -> None:
    """A z-up world (a3d's y-down world turned by Z_UP): --world-up +z gives each posed frame the
    R_tilt its pose implies, the one the y-down world gives directly; frames without a pose keep
    their estimate."""
    z_up = make_pose(
        np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]), np.zeros(3)
    )  # y-down -> z-up
    folder = tmp_path / "rgbd_dataset_freiburg1_desk"
    write_tum(folder, synth_frames((3, 4)), [100.0, 100.1])
    write_tum_trajectory(folder, [100.09, 100.11], [z_up @ pose_of(1), z_up @ pose_of(1)])
    out = tmp_path / "det.jsonl"
    argv = [str(folder), "--model", "fake.onnx", "--output", str(out), "--headless", "--world-up", "+z"]
    assert run_cli.main(argv) == 0
    first, second = (json.loads(line) for line in out.read_text().splitlines())
    assert first["gravity"] == "estimated" and "pose" not in first  # before the trajectory
    assert second["gravity"] == "given"
    np.testing.assert_allclose(second["R_tilt"], rtilt_from_pose(pose_of(1)), atol=1e-9)
    capsys.readouterr()
    plain = write_scene_folder(tmp_path / "plain", ["a"])
    assert (
        run_cli.main(
            [str(plain), "--model", "fake.onnx", "--output", str(out), "--headless", "--world-up", "+z"]
        )
        == 2
    )
    assert "--world-up needs camera poses, and this source has none" in capsys.readouterr().err
    with pytest.raises(InputError, match="--world-up: expected one of"):
        down_of_up_axis("up")
