"""A frame the depth odometry loses is placed by its image features (a3d.runtime.mapping.relocalise)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from a3d.runtime.cli.poses import main
from a3d.runtime.mapping.odometry import DepthTracker
from a3d.runtime.mapping.relocalise import FeatureMap, _distinct
from a3d.runtime.sources.folder import TRACKING_FILE, list_frames, read_meta, write_frame
from a3d.runtime.structures.pose import invert_pose, make_pose, rotation_deg
from tests.helpers.textured_room import INTRINSICS, SIZE, render


def camera(yaw_deg: float, position: tuple[float, float, float]) -> np.ndarray:
    """A camera pose (camera to world, y down) turned by ``yaw_deg`` and looking 12 degrees down."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    c, s = math.cos(math.radians(12)), math.sin(math.radians(12))
    down = np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    return make_pose(turn @ down, np.asarray(position, np.float64))


# a start, then two snapshots half a metre and 15 to 20 degrees on: far past one odometry step
POSES = [camera(0, (0, 0, 0)), camera(20, (0.5, -0.1, 0.3)), camera(-15, (-0.4, 0.0, 0.6))]


def errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(centimetres, degrees) between two poses."""
    off = invert_pose(truth) @ estimate
    return 100 * float(np.linalg.norm(off[:3, 3])), rotation_deg(off[:3, :3])


def test_snapshots_too_far_apart_for_the_odometry_are_placed_by_their_features() -> None:
    tracker = DepthTracker(INTRINSICS, SIZE)
    outcomes = [tracker.track(depth, color) for color, depth in map(render, POSES)]
    assert [o.relocalised for o in outcomes] == [False, True, True]
    assert all("image features" in o.note and "odometry lost it" in o.note for o in outcomes[1:])
    for outcome, truth in zip(outcomes, POSES, strict=True):
        centimetres, degrees = errors(outcome.pose, invert_pose(POSES[0]) @ truth)
        assert centimetres < 2.0 and degrees < 0.5
        assert outcome.agreement > 0.9


def test_without_texture_or_without_depth_agreement_a_lost_frame_stays_lost() -> None:
    tracker = DepthTracker(INTRINSICS, SIZE)
    color, depth = render(POSES[0])
    tracker.track(depth, color)
    color, depth = render(POSES[1])
    plain = tracker.track(depth, np.full_like(color, 128))  # no features to match
    assert plain.pose is None and "no keyframe's image features place it either" in plain.note
    elsewhere = tracker.track(np.full_like(depth, 0.7), color)  # the features match, the depth does not
    assert elsewhere.pose is None and "placed by its image features, only" in elsewhere.note


def test_a_keyframe_is_kept_only_once_the_camera_has_moved() -> None:
    features = FeatureMap(INTRINSICS)
    color, depth = render(POSES[0])
    gray = color[..., 0]
    assert features.add(gray, depth, POSES[0])
    assert not features.add(gray, depth, POSES[0] @ make_pose(np.eye(3), np.array([0.05, 0, 0])))
    assert features.add(gray, depth, POSES[0] @ make_pose(np.eye(3), np.array([0.25, 0, 0])))
    assert len(features.keyframes) == 2
    located = features.locate(*(render(POSES[1])[0][..., 0], render(POSES[1])[1]))
    assert located is not None and located.inliers >= 30
    assert min(errors(pose, POSES[1])[0] for pose in located.poses) < 2.0


def test_a3d_poses_says_which_frames_its_features_placed(tmp_path: Path, capsys) -> None:
    snapshots = tmp_path / "snapshots"
    for i, pose in enumerate(POSES):
        color, depth = render(pose)
        write_frame(snapshots, f"s{i}", color, depth, intrinsics_override=INTRINSICS)
    out = tmp_path / "posed"
    assert main([str(snapshots), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "s1.color.png: the odometry lost it" in err and "s2.color.png: the odometry lost it" in err
    records = [json.loads(line) for line in (out / TRACKING_FILE).read_text().splitlines()]
    assert [r["relocalised"] for r in records] == [False, True, True]
    poses = [read_meta(ref).pose for ref in list_frames(out)]
    for i in (1, 2):  # each relative to the first, as tracked (the world's heading is the first camera's)
        centimetres, degrees = errors(invert_pose(poses[0]) @ poses[i], invert_pose(POSES[0]) @ POSES[i])
        assert centimetres < 2.0 and degrees < 0.5


def test_poses_within_a_centimetre_and_half_a_degree_of_one_before_are_tried_once() -> None:
    near, far = (make_pose(np.eye(3), np.array([x, 0.0, 0.0])) for x in (0.005, 0.05))
    turned = camera(1.0, (0, 0, 0)) @ invert_pose(camera(0.0, (0, 0, 0)))  # a degree about gravity
    assert [p[0, 3] for p in _distinct([np.eye(4), near, far, turned])] == [0.0, 0.05, 0.0]
