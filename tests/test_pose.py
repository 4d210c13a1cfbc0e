"""Camera poses: the rigid-transform check, TUM quaternions, slerp and trajectory interpolation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.sources.trajectory import read_trajectory
from a3d.runtime.structures.pose import (
    check_pose,
    invert_pose,
    make_pose,
    quaternion_to_rotation,
    rigid_fit,
    rotation_deg,
    slerp,
    transform_points,
)


def R_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quaternion_z(angle: float) -> np.ndarray:
    return np.array([0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)])


def test_a_rigid_pose_is_accepted_and_snapped_to_an_exact_rotation() -> None:
    T = make_pose(R_z(0.3), [1.0, 2.0, 3.0])
    T[:3, :3] += 2e-4  # rounding of a text file
    checked = check_pose(T, "pose")
    np.testing.assert_allclose(checked[:3, :3] @ checked[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(checked[:3, :3], R_z(0.3), atol=1e-3)
    np.testing.assert_array_equal(checked[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(invert_pose(checked) @ checked, np.eye(4), atol=1e-12)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda T: T * np.diag([1.1, 1.1, 1.1, 1.0]), r"pose: not a rigid transform: .* not orthonormal"),
        (lambda T: T @ np.diag([1.0, 1.0, -1.0, 1.0]), r"pose: not a rigid transform: det R = -1"),
        (lambda T: T + np.array([[0, 0, 0, 0]] * 3 + [[0, 0, 0.5, 0]]), r"pose: last row must be 0 0 0 1"),
        (lambda T: T * np.nan, r"pose: has NaN or infinite entries"),
        (lambda T: T[:3], r"pose: expected a 4x4 camera-to-world matrix, got shape \(3, 4\)"),
    ],
)
def test_a_pose_that_is_no_rigid_transform_is_one_line(change, message: str) -> None:
    with pytest.raises(InputError, match=message):
        check_pose(change(make_pose(R_z(0.3), [1.0, 2.0, 3.0])), "pose")


def test_quaternions_and_slerp() -> None:
    np.testing.assert_allclose(quaternion_to_rotation(quaternion_z(0.8), "q"), R_z(0.8), atol=1e-12)
    np.testing.assert_allclose(
        quaternion_to_rotation(2 * quaternion_z(0.8) / 1.999, "q"), R_z(0.8), atol=1e-12
    )
    halfway = slerp(quaternion_z(0.2), quaternion_z(1.0), 0.25)
    np.testing.assert_allclose(quaternion_to_rotation(halfway, "q"), R_z(0.4), atol=1e-12)
    # q and -q are one rotation: slerp takes the short way, not round the long one
    short = slerp(quaternion_z(0.2), -quaternion_z(0.6), 0.5)
    np.testing.assert_allclose(quaternion_to_rotation(short, "q"), R_z(0.4), atol=1e-12)
    with pytest.raises(InputError, match=r"q: quaternion qx qy qz qw has norm 0\.5, not 1"):
        quaternion_to_rotation(0.5 * quaternion_z(0.8), "q")


def test_trajectory_interpolates_and_says_why_a_time_has_no_pose(tmp_path: Path) -> None:
    path = tmp_path / "groundtruth.txt"
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, x, angle in ((10.00, 0.0, 0.0), (10.01, 1.0, 0.1), (10.02, 2.0, 0.2), (10.50, 3.0, 0.3)):
        lines.append(f"{t:.4f} {x} 0 5 " + " ".join(f"{q:.9f}" for q in quaternion_z(angle)))
    lines += ["10.60 1 2 3", "10.70 0 0 0 0 0 0 0"]  # malformed: too few numbers, a zero quaternion
    path.write_text("\n".join(lines) + "\n")
    problems: list[str] = []
    trajectory = read_trajectory(path, problems)
    assert len(trajectory) == 4
    assert problems[0] == f"{path}:6: expected 'timestamp tx ty tz qx qy qz qw', got '10.60 1 2 3'"
    assert problems[1] == f"{path}:7: quaternion qx qy qz qw has norm 0, not 1"

    pose, why = trajectory.pose_at(10.0125)
    assert why == ""
    np.testing.assert_allclose(pose[:3, 3], [1.25, 0.0, 5.0], atol=1e-9)
    np.testing.assert_allclose(pose[:3, :3], R_z(0.125), atol=1e-9)
    pose, _ = trajectory.pose_at(10.02)  # a sample's own time
    np.testing.assert_allclose(pose, make_pose(R_z(0.2), [2.0, 0.0, 5.0]), atol=1e-9)

    assert trajectory.pose_at(9.99) == (
        None,
        "time 9.990000 is outside groundtruth.txt's span [10.000000, 10.500000]",
    )
    assert trajectory.pose_at(10.3) == (
        None,
        "the poses of groundtruth.txt around time 10.300000 are 0.480 s apart (more than 0.05 s)",
    )
    assert trajectory.pose_at(10.3, max_gap=0.5)[0] is not None


def test_rigid_fit_finds_the_move_between_two_point_sets_and_rotation_deg_its_angle() -> None:
    turn = quaternion_to_rotation(np.array([0.0, math.sin(0.25), 0.0, math.cos(0.25)]), "q")  # 0.5 rad, y
    move = make_pose(turn, np.array([0.4, -0.1, 1.2]))
    points = np.random.default_rng(3).uniform(-2, 2, (20, 3))
    np.testing.assert_allclose(rigid_fit(points, transform_points(move, points)), move, atol=1e-9)
    assert rotation_deg(turn) == pytest.approx(math.degrees(0.5))
    assert rotation_deg(np.eye(3)) == 0.0
