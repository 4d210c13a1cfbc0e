"""bench.real_room's geometry: drawn-once boxes into the tracked world and back, and one object's
boxes from several views grouped as one."""

from __future__ import annotations

import math

import numpy as np

from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from a3d.runtime.structures.pose import make_pose
from bench.real_room import View, group, in_view, in_world


def test_a_box_taken_into_the_world_and_back_into_its_view_is_the_same_box() -> None:
    R_tilt = rtilt_from_pitch_roll(math.radians(-15), math.radians(2))
    c, s = math.cos(0.6), math.sin(0.6)
    # camera to a world whose y is down (a3d-poses'): the camera's tilt frame, turned about gravity
    pose = make_pose(np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ R_tilt, np.array([0.5, -1.3, 2.0]))
    box = np.array([0.4, 0.3, 2.5, 0.9, 0.5, 0.8, 0.3])
    world = in_world(box, R_tilt, pose)
    np.testing.assert_allclose(world[3:6], box[3:6], atol=1e-9)  # sizes kept
    back = in_view(world, View("f", "chair", box, R_tilt, world), pose)
    np.testing.assert_allclose(back, box, atol=1e-9)


def test_one_objects_boxes_from_several_views_are_grouped_and_neighbours_kept_apart() -> None:
    def view(frame: str, name: str, x: float) -> View:
        box = np.array([x, 1.0, 3.0, 0.5, 0.5, 0.9, 0.0])
        return View(frame, name, box, np.eye(3), box)

    seen = [("a", "chair", 0.0), ("a", "chair", 0.6), ("b", "chair", 0.1), ("b", "table", 0.0)]
    objects = group([view(*v) for v in seen])
    assert [[(v.frame, v.name) for v in o] for o in objects] == [
        [("a", "chair"), ("b", "chair")],  # 10 cm apart: one chair seen twice
        [("a", "chair")],  # 60 cm on: its neighbour
        [("b", "table")],  # another class, whatever the place
    ]
