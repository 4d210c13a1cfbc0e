"""a3d-run --map on a source without poses tracks them from its depth (a3d.runtime.mapping.tracked_poses)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from a3d.runtime.cli.run import TRACKING_NOTE, main
from a3d.runtime.mapping.odometry import DepthTracker, TrackerConfig
from a3d.runtime.mapping.tracked_poses import FramePoses, with_tracked_poses
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.folder import write_frame
from a3d.runtime.structures.pose import invert_pose, make_pose
from tests.helpers.textured_room import INTRINSICS, SIZE, render
from tests.test_relocalise import POSES, camera, errors

# a hand-held start, a few centimetres and degrees a frame, then the two snapshots that only
# image features place
WALK = [camera(3 * i, (0.03 * i, 0.0, 0.02 * i)) for i in range(6)] + POSES[1:]


def test_a_run_without_poses_maps_its_frames_with_poses_tracked_from_their_depth(
    tmp_path: Path, capsys
) -> None:
    frames = tmp_path / "frames"
    for i, pose in enumerate(WALK):
        color, depth = render(pose)
        write_frame(frames, f"s{i}", color, depth, intrinsics_override=INTRINSICS)
    color, depth = render(WALK[-1])
    write_frame(frames, "s9", color, np.full_like(depth, 0.7), intrinsics_override=INTRINSICS)  # depth lies
    out, world_map = tmp_path / "det.jsonl", tmp_path / "map.json"
    assert main([str(frames), "--headless", "--output", str(out), "--map", str(world_map)]) == 0
    assert TRACKING_NOTE in capsys.readouterr().err
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [line["frame"] for line in lines] == [f"s{i}" for i in range(len(WALK))] + ["s9"]
    for line, truth in zip(lines, WALK, strict=False):
        centimetres, degrees = errors(np.array(line["pose"]), invert_pose(WALK[0]) @ truth)
        assert centimetres < 3.0 and degrees < 0.5  # frame to model, without a3d-poses' refinement
    placed = [
        line["frame"] for line in lines[:-1] if any("image features" in n for n in line.get("notes", []))
    ]
    assert placed == [f"s{len(WALK) - 2}", f"s{len(WALK) - 1}"]  # the snapshots, and they say so
    lost = lines[-1]
    assert lost.get("pose") is None and any(n.startswith("not tracked: ") for n in lost["notes"])
    written = json.loads(world_map.read_text())
    assert written["frames_mapped"] == len(WALK) and sum(written["frames_skipped"].values()) == 1


def test_a_posed_source_keeps_its_own_poses(tmp_path: Path, capsys) -> None:
    frames = tmp_path / "frames"
    moved = make_pose(np.eye(3), np.array([1.0, 0.0, 2.0]))  # tracking would start at the origin
    shifted = [moved @ pose for pose in WALK[:2]]
    for i, pose in enumerate(shifted):
        color, depth = render(pose)
        write_frame(frames, f"s{i}", color, depth, intrinsics_override=INTRINSICS, pose=pose)
    out = tmp_path / "det.jsonl"
    assert main([str(frames), "--headless", "--output", str(out), "--map", str(tmp_path / "map.json")]) == 0
    assert TRACKING_NOTE not in capsys.readouterr().err
    for line, pose in zip(out.read_text().splitlines(), shifted, strict=True):
        np.testing.assert_allclose(json.loads(line)["pose"], pose, atol=1e-6)  # as given, not tracked


def test_closing_the_tracked_loaders_closes_the_source() -> None:
    closed = []

    def source():
        try:
            while True:
                yield FrameLoader("f", "camera", lambda: None)
        finally:
            closed.append(True)

    loaders = with_tracked_poses(source(), FramePoses())
    next(loaders)
    loaders.close()
    assert closed == [True]


def test_a_model_at_half_the_frames_size_tracks_the_same_path() -> None:
    # frames at 320 x 240, the model, the odometry and the agreement at 160 x 120, features at 320
    tracker = DepthTracker(INTRINSICS, SIZE, TrackerConfig(model_side=SIZE[1] // 2))
    for pose in WALK:
        color, depth = render(pose)
        tracked = tracker.track(depth, color)
        centimetres, degrees = errors(tracked.pose, invert_pose(WALK[0]) @ pose)
        assert centimetres < 3.0 and degrees < 0.5
