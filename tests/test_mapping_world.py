"""Boxes between posed cameras and the gravity-aligned world, and the world_boxes.json file."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.mapping.world import box_differences, boxes_to_camera, boxes_to_world, rtilt_from_pose
from a3d.runtime.mapping.world_boxes import WorldBoxes, read_world_boxes, write_world_boxes
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from a3d.runtime.structures.pose import make_pose


def R_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def camera_pose(heading: float, pitch: float, roll: float, position) -> tuple[np.ndarray, np.ndarray]:
    R_tilt = rtilt_from_pitch_roll(pitch, roll)
    return make_pose(R_y(heading) @ R_tilt, position), R_tilt


def test_a_box_turns_with_the_heading_and_moves_with_the_camera() -> None:
    pose, R_tilt = camera_pose(0.5, -0.3, 0.04, [2.0, -1.5, 1.0])
    np.testing.assert_allclose(rtilt_from_pose(pose), R_tilt, atol=1e-12)
    # a box 3 m straight ahead in the tilt frame, yaw 0.2 there: in the world it is 3 m along the
    # heading from the camera and its yaw is 0.2 + 0.5
    in_tilt = np.array([0.0, 0.4, 3.0])
    box = np.array([[*(R_tilt.T @ in_tilt), 1.2, 0.6, 0.8, 0.2]])
    world = boxes_to_world(box, R_tilt, pose)
    expected_centre = np.array([2.0, -1.5, 1.0]) + R_y(0.5) @ in_tilt
    np.testing.assert_allclose(world[0], [*expected_centre, 1.2, 0.6, 0.8, 0.7], atol=1e-12)
    np.testing.assert_allclose(boxes_to_camera(world, pose, R_tilt), box, atol=1e-12)


def test_box_differences_respect_each_box_s_symmetry() -> None:
    yaw, z = np.eye(7)[6], np.eye(7)[2]
    box = np.array([1.0, 2.0, 3.0, 1.0, 0.5, 0.7, 1.5])
    assert box_differences(box, box - np.pi * yaw)[0] < 1e-12  # the same box
    assert box_differences(box, box - np.pi / 2 * yaw)[0] == pytest.approx(np.pi / 2)  # not: l != w
    square = np.array([1.0, 2.0, 3.0, 0.5, 0.5, 0.7, 1.5])
    assert box_differences(square, square - np.pi / 2 * yaw)[0] < 1e-12
    assert box_differences(box, box + 1e-3 * z)[0] == pytest.approx(1e-3)


def test_world_boxes_file_round_trips_and_refuses_bad_objects(tmp_path: Path) -> None:
    boxes = WorldBoxes(
        ["chair", "bed"],
        np.array([[1, -0.5, 2, 0.6, 0.5, 1.0, 0.3], [0, -0.4, 0, 2, 1, 0.8, -1.2]]),
        np.array([4, 9]),
    )
    path = tmp_path / "world_boxes.json"
    write_world_boxes(path, boxes)
    back = read_world_boxes(path)
    assert back.classes == ["chair", "bed"] and back.ids.tolist() == [4, 9]
    np.testing.assert_allclose(back.boxes, boxes.boxes)
    document = json.loads(path.read_text())
    for change, message in (
        ({"class": "cat"}, r"objects\[0\]\.class 'cat' is not one of the 19 classes"),
        ({"size": [1, 0, 1]}, r"objects\[0\]\.size must be three positive extents"),
        ({"centre": [1, 2]}, r"objects\[0\]\.centre must be 3 finite numbers"),
        ({"colour": "red"}, r"objects\[0\]: unknown key 'colour'"),
        ({"id": 9}, r"object ids must be unique"),
    ):
        bad = {"objects": [{**document["objects"][0], **change}, document["objects"][1]]}
        path.write_text(json.dumps(bad))
        with pytest.raises(InputError, match=f"^{path}: {message}"):
            read_world_boxes(path)
    # l < w is the same box as (w, l, yaw + pi/2): read canonical
    path.write_text(
        json.dumps({"objects": [{"class": "desk", "centre": [0, 0, 0], "size": [0.5, 1.0, 0.7], "yaw": 0.0}]})
    )
    np.testing.assert_allclose(read_world_boxes(path).boxes[0, 3:], [1.0, 0.5, 0.7, np.pi / 2])
