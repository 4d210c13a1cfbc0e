"""Camera poses from a bag's PoseStamped topic: interpolated to each colour stamp, none outside the
topic's span, across a gap or without a pose topic, and a bad quaternion costs only its pose;
without a pose topic, /tf from the world to the colour camera's frame."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from a3d.runtime.cli import run as run_cli
from a3d.runtime.errors import InputError
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.runtime.structures.pose import make_pose
from tests.bag_files import PERIOD, POSE, T0, stamp_as_read, write_driver_bag
from tests.helpers.runtime_frames import FakeModel
from tests.synth_frames import K, folder_frames, write_synth_folder

SPIN = 10.0  # rad/s about y: 0.2 rad between poses 0.02 s apart, so slerp is not its linear fallback


@pytest.fixture(scope="module")
def frames(tmp_path_factory: pytest.TempPathFactory) -> list:
    return folder_frames(write_synth_folder(tmp_path_factory.mktemp("frames")))[:2] * 2  # four frames


def motion(t: float) -> tuple[np.ndarray, np.ndarray]:
    """Position and quaternion (x, y, z, w) at time t: linear in t, a constant spin about y."""
    u = t - T0
    half = (0.3 + SPIN * u) / 2
    return np.array([1.0 + u, -0.5, 2.0 * u]), np.array([0.0, math.sin(half), 0.0, math.cos(half)])


def pose_matrix(t: float) -> np.ndarray:
    position, q = motion(t)
    a = 2 * math.atan2(q[1], q[3])
    R = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    return make_pose(R, position)


def posed_frames(path: Path, frames: list, stamps: list[float], ros2: bool, **extra: object) -> tuple:
    """The source and frames of a bag whose camera moves by ``motion``, posed at ``stamps``."""
    poses = [(t, *motion(stamp_as_read(t))) for t in stamps]
    write_driver_bag(path, frames, K, ros2=ros2, with_raw_depth=False, poses=poses)
    source = open_source(path, SourceOptions(extra=extra))
    return source, [loader.load() for loader in source]


@pytest.mark.parametrize("ros2", [False, True], ids=["ros1", "ros2"])
def test_frames_get_the_pose_topic_interpolated_to_their_colour_stamps(
    frames: list, tmp_path: Path, ros2: bool
) -> None:
    stamps = [T0 + 0.01 + 0.02 * k for k in range(6)]  # frame 0 (at T0) is before the first pose
    source, loaded = posed_frames(tmp_path / ("bag" if ros2 else "p.bag"), frames, stamps, ros2)
    assert source.has_poses and not source.incomplete
    first, *rest = loaded
    assert first.pose is None and "outside" in first.pose_note and POSE in first.pose_note
    for frame in rest:
        np.testing.assert_allclose(frame.pose, pose_matrix(frame.timestamp), rtol=0, atol=1e-9)
        assert frame.pose_note == ""
    assert [f.timestamp for f in loaded] == pytest.approx([T0 + i * PERIOD for i in range(4)], abs=1e-6)


def test_a_bad_quaternion_costs_its_frame_the_pose_with_a_note(frames: list, tmp_path: Path) -> None:
    path = tmp_path / "bag"
    stamps = [T0 + i * PERIOD for i in range(4)]
    poses = [(t, *motion(stamp_as_read(t))) for t in stamps]
    poses[2] = (stamps[2], poses[2][1], np.zeros(4))  # zero norm: no rotation at all
    write_driver_bag(path, frames, K, ros2=True, with_raw_depth=False, poses=poses)
    source = open_source(path, SourceOptions())
    loaded = [loader.load() for loader in source]
    assert len(source.incomplete) == 1 and "norm 0" in source.incomplete[0]
    assert loaded[2].pose is None and loaded[2].pose_note.startswith("no pose: ")
    assert "apart" in loaded[2].pose_note  # its neighbours are 2/30 s apart, beyond the 0.05 s gap
    for i in (0, 1, 3):
        np.testing.assert_allclose(loaded[i].pose, pose_matrix(loaded[i].timestamp), rtol=0, atol=1e-9)
    relaxed = open_source(path, SourceOptions(extra={"max_pose_gap": 0.1}))
    frame = list(relaxed)[2].load()
    np.testing.assert_allclose(frame.pose, pose_matrix(frame.timestamp), rtol=0, atol=1e-9)


def test_a_bag_without_a_pose_topic_gives_frames_without_poses(frames: list, tmp_path: Path) -> None:
    path = tmp_path / "bag"
    write_driver_bag(path, frames, K, ros2=True, with_raw_depth=False)
    source = open_source(path, SourceOptions())
    assert not source.has_poses
    assert all(f.pose is None and f.pose_note == "" for f in (loader.load() for loader in source))
    with pytest.raises(InputError, match="pose_topic: /odom is not a PoseStamped or Odometry topic"):
        open_source(path, SourceOptions(extra={"pose_topic": "/odom"}))


def test_of_several_pose_topics_none_is_guessed_and_one_can_be_named(frames: list, tmp_path: Path) -> None:
    path = tmp_path / "bag"
    poses = [(t, *motion(stamp_as_read(t))) for t in (T0 + i * PERIOD for i in range(4))]
    write_driver_bag(
        path, frames, K, ros2=True, with_raw_depth=False, poses=poses, pose_topics=(POSE, "/slam")
    )
    guessed = open_source(path, SourceOptions())
    assert not guessed.has_poses
    assert "several pose topics (/camera/pose, /slam), none used" in guessed.incomplete[0]
    named = open_source(path, SourceOptions(extra={"pose_topic": "/slam"}))
    for frame in (loader.load() for loader in named):
        np.testing.assert_allclose(frame.pose, pose_matrix(frame.timestamp), rtol=0, atol=1e-9)


@pytest.mark.parametrize("parent", ["map", "camera_link"])
def test_without_a_pose_topic_tf_from_the_world_to_the_camera_poses_it(
    frames: list, tmp_path: Path, parent: str
) -> None:
    path = tmp_path / "bag"
    stamps = [T0 + 0.02 * k for k in range(6)]
    poses = [(t, *motion(stamp_as_read(t))) for t in stamps]
    write_driver_bag(path, frames, K, ros2=True, with_raw_depth=False, tf=poses, tf_parent=parent)
    source = open_source(path, SourceOptions())
    loaded = [loader.load() for loader in source]
    if parent == "camera_link":  # the camera on its mount, not in the world
        assert not source.has_poses and all(f.pose is None for f in loaded)
        return
    assert source.has_poses
    for frame in loaded:
        np.testing.assert_allclose(frame.pose, pose_matrix(frame.timestamp), rtol=0, atol=1e-9)


def test_a3d_run_pose_topic_puts_the_poses_in_the_lines(
    frames: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: FakeModel())
    stamps = [T0 + i * PERIOD for i in range(4)]
    source, loaded = posed_frames(tmp_path / "bag", frames, stamps, True)
    output = tmp_path / "det.jsonl"
    flags = ["--model", "fake.onnx", "--output", str(output), "--headless"]
    assert run_cli.main([str(source.path), *flags, "--pose-topic", POSE]) == 0
    lines = [json.loads(line) for line in output.read_text().splitlines()]
    assert [line["pose"] for line in lines] == [frame.pose.tolist() for frame in loaded]
    assert run_cli.main([str(source.path), *flags, "--pose-topic", "/odom"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    says = f"--pose-topic: /odom is not a PoseStamped or Odometry topic of {source.path}"
    assert err == f"a3d-run: error: {says}"
