"""bench.real_room: one object's drawn-once boxes from several views grouped as one."""

from __future__ import annotations

import numpy as np

from bench.real_room import View, group


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
