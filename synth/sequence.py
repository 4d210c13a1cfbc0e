"""One room seen by a camera moving round it: a posed RGB-D sequence (``a3d-synth OUT --sequence N``).

The room is that of the run's seed (``generate_frame(seed)`` furnishes it: its objects, materials
and lights), static; only the camera moves, once round an ellipse about the room's centre, looking
inward, with a gentle swing of heading, height, pitch and roll (``orbit``); or twice
(``--loops 2``): a hand-held camera's loop and then a robot's, lower and on another path, as a
room recorded once is seen again by a robot working in it. ``--heights`` sets each loop's camera
height instead (a robot recording its own room: ``--loops 2 --heights 1.0,1.0``); a camera lower
than a robot's metre looks down less, at about the floor point a metre-high one's axis meets.
Each view is rendered
by ``generate_frame(seed, config, camera=pose, noise_seed=...)``, so every frame has its own sensor
noise and the per-frame ground truth of any a3d-synth frame.

The world is the room's gravity-aligned frame in a3d's convention (a3d.runtime.mapping.world):
x and z along the room's walls from its corner, y along gravity pointing down (y = -height above
the floor). ``world_pose`` is each view's camera-to-world pose (written as ``"pose"`` in the frame's
meta.json) and ``world_boxes`` the class objects' boxes in that world (``world_boxes.json``), so
that a frame's ground-truth boxes are the world boxes moved into its camera.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from a3d.runtime.mapping.world_boxes import WorldBoxes
from a3d.runtime.structures.boxes import boxes_array
from a3d.runtime.structures.geometry import canonical_boxes
from a3d.runtime.structures.pose import make_pose
from a3d.synth.camera import CameraPose
from a3d.synth.layout import Layout, point_rect_distance
from a3d.synth.scene import SceneConfig
from a3d.synth.world import furnish_world

WALL_MARGIN = 0.45  # metres between the path and the walls
CLEARANCE = 0.35  # metres between the path and any furniture footprint, where the room allows
PATH_SCALES = (0.75, 0.6, 0.9, 0.45, 0.3)  # of the room's half extents, tried in this order
HEIGHT_M, HEIGHT_SWING_M = 1.4, 0.2
ROBOT_HEIGHT_M = 1.0  # a robot's camera, for a sequence's second loop
LOOP_HEIGHTS_M = (HEIGHT_M, ROBOT_HEIGHT_M)  # the loops' camera heights unless given
HEIGHT_RANGE_M = (0.3, 2.0)  # a loop's camera height, given
PITCH_DEG, PITCH_SWING_DEG, ROLL_SWING_DEG, HEADING_SWING = -20.0, 6.0, 2.0, 0.15


def room_of(seed: int, config: SceneConfig) -> tuple[str, Layout]:
    """The furnished room ``generate_frame(seed, config)`` renders (the same first draws)."""
    return furnish_world(np.random.default_rng(seed), config.room_type, config.clutter, config.labelled)


def orbit(
    layout: Layout, frames: int, loops: int = 1, heights: Sequence[float] | None = None
) -> list[CameraPose]:
    """``frames`` camera poses round the room's centre, looking inward (module docstring).

    One loop: a hand-held camera's, ``HEIGHT_M`` high, on the first of ``PATH_SCALES`` (of the
    room's half extents, less ``WALL_MARGIN``) on which fewest poses stand within ``CLEARANCE`` of a
    piece of furniture. Two loops (the second half of the frames): then a robot's, ``ROBOT_HEIGHT_M``
    high, the other way round on the next clearest path, so that its views are of the same room but
    none is the first loop's again. ``heights`` (one per loop, within ``HEIGHT_RANGE_M``) replaces
    those heights.
    """
    heights = loop_heights(loops, heights)
    if frames < loops:
        raise ValueError(f"loops: expected at least as many frames as loops, got {frames} for {loops}")
    first = frames if loops == 1 else frames // 2
    poses = _loop(layout, 2 * np.pi * np.arange(first) / first, heights[0], rank=0)
    if loops == 2:
        rest = frames - first
        poses += _loop(layout, -2 * np.pi * (np.arange(rest) + 0.5) / rest, heights[1], rank=1)
    return poses


def loop_heights(loops: int, heights: Sequence[float] | None = None) -> tuple[float, ...]:
    """Each loop's camera height: ``heights`` checked (one per loop, within ``HEIGHT_RANGE_M``;
    ValueError naming what is wrong), or the default ``LOOP_HEIGHTS_M``."""
    if loops not in (1, 2):
        raise ValueError(f"loops: expected 1 or 2, got {loops}")
    if heights is None:
        return LOOP_HEIGHTS_M[:loops]
    low, high = HEIGHT_RANGE_M
    if len(heights) != loops or not all(low <= h <= high for h in heights):
        shown = ",".join(f"{h:g}" for h in heights)
        raise ValueError(f"heights: expected {loops} camera height(s) in [{low}, {high}] m, got {shown}")
    return tuple(heights)


def _loop(layout: Layout, angles: np.ndarray, height: float, rank: int) -> list[CameraPose]:
    """One loop's poses at ``angles`` round the room on the ``rank``-th clearest path (orbit); under
    ``ROBOT_HEIGHT_M`` the camera's pitch scales with its height (module docstring)."""
    room = layout.room
    cx, cz = room.width / 2, room.depth / 2
    half_x, half_z = max(cx - WALL_MARGIN, 0.1), max(cz - WALL_MARGIN, 0.1)
    rects = [p.footprint() for p in layout.objects if p.render and p.item.collides]

    def blocked(scale: float) -> int:
        xs, zs = cx + scale * half_x * np.sin(angles), cz + scale * half_z * np.cos(angles)
        return sum(
            any(point_rect_distance(x, z, r) < CLEARANCE for r in rects) for x, z in zip(xs, zs, strict=True)
        )

    scale = sorted(PATH_SCALES, key=blocked)[rank]  # a stable sort keeps the first of equals
    pitch = PITCH_DEG * min(1.0, height / ROBOT_HEIGHT_M)
    poses = []
    for a in angles:
        x, z = cx + scale * half_x * math.sin(a), cz + scale * half_z * math.cos(a)
        heading = math.atan2(cx - x, cz - z) + HEADING_SWING * math.sin(3 * a)
        poses.append(
            CameraPose(
                float(x),
                float(z),
                height + HEIGHT_SWING_M * math.sin(2 * a),
                heading,
                math.radians(pitch + PITCH_SWING_DEG * math.sin(3 * a + 1.0)),
                math.radians(ROLL_SWING_DEG * math.sin(2 * a)),
            )
        )
    return poses


def world_pose(camera: CameraPose) -> np.ndarray:
    """The camera-to-world pose (4, 4) of a view: ``p_world = R_y(heading) R_tilt p_cam + (x, -height, z)``
    (the tilt frame is the world turned by the heading about gravity and moved to the camera)."""
    c, s = math.cos(camera.heading), math.sin(camera.heading)
    R_y = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return make_pose(R_y @ camera.R_tilt, [camera.x, -camera.height, camera.z])


def world_boxes(layout: Layout) -> WorldBoxes:
    """The room's rendered class objects as world boxes (the tight box of all their parts, as the
    per-frame ground truth draws them), ids in layout order."""
    classes, rows, ids = [], [], []
    for i, p in enumerate(layout.objects):
        if not p.render or p.item.cls is None:
            continue
        lo, hi = p.item.lo, p.item.hi
        x, z = p.to_room(0.5 * (lo[0] + hi[0]), 0.5 * (lo[2] + hi[2]))
        size = hi - lo
        rows.append([x, -(p.base + 0.5 * (lo[1] + hi[1])), z, size[0], size[2], size[1], p.yaw])
        classes.append(p.item.cls)
        ids.append(i)
    return WorldBoxes(classes, canonical_boxes(boxes_array(rows, len(rows))), np.array(ids, np.int64))
