"""a3d-poses and its tracker: a short recording without poses gets the poses it was rendered at
(up to the world's origin and heading), in a gravity-aligned world; frames that cannot be tracked
are named and skipped; bad input is one line and exit 2 with nothing written."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.cli import poses as poses_cli
from a3d.runtime.cli.common import EXIT_USAGE
from a3d.runtime.cli.poses import main
from a3d.runtime.errors import InputError
from a3d.runtime.mapping.odometry import DepthTracker, gravity_alignment
from a3d.runtime.mapping.world import rtilt_from_pose
from a3d.runtime.sources.folder import TRACKING_FILE, FolderSource, list_frames, read_meta, write_frame
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics, rtilt_from_pitch_roll
from a3d.runtime.structures.pose import invert_pose, make_pose
from a3d.synth.cli import frame_seed, scaled_intrinsics
from a3d.synth.scene import SceneConfig, generate_frame
from a3d.synth.sequence import orbit, room_of, world_pose

SIZE = (240, 320)  # tracking needs more than the 120 x 160 other tests render
SEED = 8  # its first views show the floor
FRAMES = 10  # the first of a 360-view loop round the room: about a degree and 3 cm apart


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[np.ndarray], list[np.ndarray]]:
    """A RealSense-like recording (intrinsics only) of a short stretch of seed 8's room, with the
    true poses and R_tilts kept aside."""
    out = tmp_path_factory.mktemp("recording")
    config = replace(SceneConfig(), image_size=SIZE, intrinsics=scaled_intrinsics(SIZE))
    _, layout = room_of(SEED, config)
    poses, tilts = [], []
    for i, camera in enumerate(orbit(layout, 360)[:FRAMES]):
        frame = generate_frame(SEED, config, camera=camera, noise_seed=frame_seed(SEED, i))
        write_frame(out, f"f{i:03d}", frame.color, frame.depth, intrinsics_override=frame.intrinsics)
        poses.append(world_pose(camera))
        tilts.append(frame.R_tilt)
    return out, poses, tilts


def relative(poses: list[np.ndarray]) -> list[np.ndarray]:
    """Each pose relative to the first: what tracking recovers, whatever the world's origin and heading."""
    first = invert_pose(poses[0])
    return [first @ p for p in poses]


def check_poses(out: Path, true_poses: list[np.ndarray], true_tilts: list[np.ndarray]) -> None:
    """Every frame of ``out`` within 4 cm and a degree of its true pose relative to the first
    (after up to 27 cm of path; bench.poses measures full-size frames), its gravity within 2
    degrees, R_tilt the pose's, and tracked with most of the model agreeing."""
    refs = list_frames(out)
    assert [r.name for r in refs] == [f"f{i:03d}" for i in range(FRAMES)]
    metas = [read_meta(r) for r in refs]
    for est, true in zip(relative([m.pose for m in metas]), relative(true_poses), strict=True):
        assert np.linalg.norm(est[:3, 3] - true[:3, 3]) < 0.04
        turn = est[:3, :3].T @ true[:3, :3]
        assert math.degrees(math.acos(np.clip((np.trace(turn) - 1) / 2, -1, 1))) < 1.0
    for meta, tilt in zip(metas, true_tilts, strict=True):
        np.testing.assert_allclose(meta.R_tilt, rtilt_from_pose(meta.pose), atol=1e-9)
        assert math.degrees(math.acos(np.clip(meta.R_tilt[1] @ tilt[1], -1, 1))) < 2.0  # gravity
    records = [json.loads(line) for line in (out / TRACKING_FILE).read_text().splitlines()]
    assert [r["tracked"] for r in records] == [True] * FRAMES
    assert [r["refined"] for r in records] == [True] * FRAMES  # against the model of all of them
    assert min(r["agreement"] for r in records) > 0.8


def test_a_recording_gets_the_poses_it_was_recorded_at(recording, tmp_path: Path) -> None:
    frames, true_poses, true_tilts = recording
    out = tmp_path / "posed"
    assert main([str(frames), "--out", str(out)]) == 0
    check_poses(out, true_poses, true_tilts)
    loaded = [loader.load() for loader in FolderSource(out)]
    assert all(f.pose is not None for f in loaded)  # a posed source for a3d-labels and a3d-world-boxes
    recorded = [loader.load() for loader in FolderSource(frames)]
    np.testing.assert_array_equal(loaded[3].depth, recorded[3].depth)  # the frames as they were


def test_frames_larger_than_the_working_size_are_tracked_at_it_and_written_as_they_are(
    recording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    frames, true_poses, true_tilts = recording
    sizes = []

    class SizeKept(DepthTracker):
        def __init__(self, intrinsics, size, config) -> None:
            sizes.append(size)
            super().__init__(intrinsics, size, config)

    monkeypatch.setattr(poses_cli, "DepthTracker", SizeKept)
    big = tmp_path / "big"  # three times the size: 720 x 960, tracked at 480 x 640
    for loader in FolderSource(frames):
        frame = loader.load()
        height, width = 3 * SIZE[0], 3 * SIZE[1]
        color = cv2.resize(frame.color, (width, height), interpolation=cv2.INTER_LINEAR)
        depth = cv2.resize(frame.depth, (width, height), interpolation=cv2.INTER_NEAREST)
        write_frame(big, frame.name, color, depth, intrinsics_override=frame.intrinsics.resized(3, 3))
    out = tmp_path / "posed"
    assert main([str(big), "--out", str(out)]) == 0
    check_poses(out, true_poses, true_tilts)
    assert sizes == [(480, 640)]
    written = next(iter(FolderSource(out))).load()
    assert written.depth.shape == (720, 960) and written.intrinsics == frame.intrinsics.resized(3, 3)


def test_every_nth_frame_and_a_frame_that_cannot_be_tracked(recording, tmp_path: Path, capsys) -> None:
    frames, _, _ = recording
    broken = tmp_path / "broken"
    broken.mkdir()
    for path in frames.iterdir():
        (broken / path.name).symlink_to(path)
    first = next(iter(FolderSource(frames))).load()
    rng = np.random.default_rng(0)
    noise = rng.uniform(0.5, 3.0, first.depth.shape).astype(np.float32)  # a view of nothing the model holds
    (broken / "f004.depth.png").unlink()
    write_frame(broken, "f004", first.color, noise, intrinsics_override=first.intrinsics)
    out = tmp_path / "posed"
    assert main([str(broken), "--out", str(out), "--every", "2"]) == 1
    err = capsys.readouterr().err
    assert "f004" in err and "not tracked" in err
    assert [r.name for r in list_frames(out)] == ["f000", "f002", "f006", "f008"]


def _one_line_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str], expected: str) -> None:
    assert main(argv) == EXIT_USAGE
    lines = capsys.readouterr().err.strip().splitlines()  # the progress lines before it, if any
    assert lines[-1].startswith("a3d-poses: error: ") and expected in lines[-1], lines
    assert sum("error" in line for line in lines) == 1


def test_bad_input_is_one_line_and_nothing_is_written(recording, tmp_path: Path, capsys) -> None:
    frames, _, _ = recording
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    _one_line_exit_2([str(frames), "--out", str(full)], capsys, "is not an empty folder")
    assert [p.name for p in full.iterdir()] == ["keep.txt"]
    _one_line_exit_2([str(frames), "--out", str(tmp_path / "o"), "--every", "0"], capsys, "--every: expected")
    empty = tmp_path / "no_depth"
    first = next(iter(FolderSource(frames))).load()
    for i in range(2):
        write_frame(
            empty, f"z{i}", first.color, np.zeros_like(first.depth), intrinsics_override=first.intrinsics
        )
    _one_line_exit_2([str(empty), "--out", str(tmp_path / "o")], capsys, "no frame could be tracked")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full", "no_depth"]  # no output, no staging


def test_tracking_a_frame_against_itself_and_a_wrong_size(recording) -> None:
    frames, _, _ = recording
    frame = next(iter(FolderSource(frames))).load()
    tracker = DepthTracker(frame.intrinsics, frame.depth.shape)
    first = tracker.track(frame.depth, frame.color)
    np.testing.assert_array_equal(first.pose, np.eye(4))
    again = tracker.track(frame.depth, frame.color)
    assert again.pose is not None and again.agreement > 0.95
    np.testing.assert_allclose(again.pose, np.eye(4), atol=6e-3)  # within a voxel of the model
    with pytest.raises(InputError, match="240x320"):
        tracker.track(np.ones((120, 160), np.float32), frame.color[::2, ::2])
    assert (
        DepthTracker(frame.intrinsics, frame.depth.shape).track(np.zeros_like(frame.depth), frame.color).pose
        is None
    )


def test_a_pose_put_off_is_refined_back_against_the_model_of_all_frames(recording) -> None:
    frames, _, _ = recording
    loaded = [loader.load() for loader in FolderSource(frames)][:4]
    tracker = DepthTracker(loaded[0].intrinsics, loaded[0].depth.shape)
    poses = [tracker.track(f.depth, f.color).pose for f in loaded]
    off = poses[2] @ make_pose(rtilt_from_pitch_roll(math.radians(1.0), 0.0), [0.02, 0.0, 0.01])
    refined = tracker.refine(loaded[2].depth, off)
    assert refined is not None
    assert np.linalg.norm(refined[:3, 3] - poses[2][:3, 3]) < 0.3 * np.linalg.norm(
        off[:3, 3] - poses[2][:3, 3]
    )
    turn = refined[:3, :3].T @ poses[2][:3, :3]
    assert math.degrees(math.acos(np.clip((np.trace(turn) - 1) / 2, -1, 1))) < 0.3


def test_gravity_alignment_turns_the_mean_down_onto_y() -> None:
    tilt = rtilt_from_pitch_roll(math.radians(-25), math.radians(4))  # the first camera's
    down = tilt[1]  # gravity in that camera
    yaw = make_pose(np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), np.zeros(3))  # a second camera
    poses = [np.eye(4), invert_pose(yaw)]
    downs = [down, yaw[:3, :3] @ down]  # the same gravity, seen from the turned camera
    alignment = gravity_alignment(poses, downs)
    np.testing.assert_allclose(alignment.rotation @ down, [0, 1, 0], atol=1e-9)
    assert alignment.frames == 2 and alignment.spread_deg < 1e-6
    with pytest.raises(ValueError, match="gravity"):
        gravity_alignment([], [])


def test_gravity_from_walls_alone_only_when_no_frame_shows_a_floor(capsys) -> None:
    K = Intrinsics(300.0, 300.0, 159.5, 119.5)
    u = np.arange(320)[None, :] - 159.5
    wall = np.ones((240, 1), np.float32) * (600.0 / (300.0 + 0.5 * u)).astype(np.float32)  # turned about y
    frame = Frame("w", np.zeros((240, 320, 3), np.uint8), wall, K)
    tracks = poses_cli.Tracks(poses={0: np.eye(4)})
    poses_cli.add_down(tracks, 0, frame)
    assert not tracks.downs and list(tracks.wall_downs) == [0]
    turn = poses_cli.world_turn(tracks, Path("rec"))
    np.testing.assert_allclose(turn[:3, :3] @ tracks.wall_downs[0], [0, 1, 0], atol=1e-9)
    assert "walls alone" in capsys.readouterr().err
    tracks.downs[0] = np.array([0.0, 0.0, 1.0])  # a frame that shows a floor wins over the walls
    turn = poses_cli.world_turn(tracks, Path("rec"))
    np.testing.assert_allclose(turn[:3, :3] @ [0.0, 0.0, 1.0], [0, 1, 0], atol=1e-9)
    with pytest.raises(InputError, match="which way is down"):
        poses_cli.world_turn(poses_cli.Tracks(poses={0: np.eye(4)}), Path("rec"))
