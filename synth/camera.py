"""The handheld Kinect-like camera: its pose in the room and the frame changes it implies.

A pose is a position ``(x, z)`` on the room floor plan, a height above the floor, a heading
``phi`` (room-frame yaw of the viewing direction, the yaw convention of docs/conventions.md
"3D boxes"), a pitch (negative = looking down) and a roll, all radians. Frames (all metres):

* tilt frame = the room turned by ``-phi`` about gravity and moved to the camera: x right,
  y down (along gravity), z along the horizontal heading; ``p_tilt = R_y(-phi) (p_room - cam)``
  with the room height mapped to ``y = height - h``;
* camera frame: ``p_cam = R_tilt.T @ p_tilt`` with ``R_tilt = R_x(pitch) R_z(roll)``
  (``a3d.runtime.structures.geometry.rtilt_from_pitch_roll``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from a3d.runtime.structures.geometry import Intrinsics, rtilt_from_pitch_roll
from a3d.synth.layout import Layout, point_rect_distance


@dataclass(frozen=True)
class CameraPose:
    """Where the camera is in the room (metres, radians; see the module docstring)."""

    x: float
    z: float
    height: float
    heading: float
    pitch: float
    roll: float

    @property
    def R_tilt(self) -> np.ndarray:
        return rtilt_from_pitch_roll(self.pitch, self.roll)

    def room_to_tilt(self, x: np.ndarray, h: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Tilt-frame points (..., 3) of room points (x, height h, z)."""
        c, s = math.cos(self.heading), math.sin(self.heading)
        dx, dz = np.asarray(x) - self.x, np.asarray(z) - self.z
        return np.stack([c * dx - s * dz, self.height - np.asarray(h), s * dx + c * dz], axis=-1)

    def tilt_to_room(self, points: np.ndarray) -> np.ndarray:
        """Room points (..., 3) as (x, height h, z) of tilt-frame points: ``room_to_tilt``'s inverse."""
        p = np.asarray(points, np.float64)
        c, s = math.cos(self.heading), math.sin(self.heading)
        dx, dz = c * p[..., 0] + s * p[..., 2], -s * p[..., 0] + c * p[..., 2]
        return np.stack([self.x + dx, self.height - p[..., 1], self.z + dz], axis=-1)


@dataclass(frozen=True)
class CameraRanges:
    """Handheld-camera pose ranges: height above the floor (m), pitch and roll (degrees)."""

    height: tuple[float, float] = (1.0, 1.8)
    pitch_deg: tuple[float, float] = (-35.0, -5.0)
    roll_deg: tuple[float, float] = (-5.0, 5.0)
    clearance: float = 0.4  # no furniture footprint within this distance of the camera (m)
    candidates: int = 150


def choose_camera(
    layout: Layout, rng: np.random.Generator, ranges: CameraRanges, K: Intrinsics, image_size: tuple[int, int]
) -> CameraPose:
    """The best of ``ranges.candidates`` random poses: most annotatable objects' centres in view.

    A candidate must stand clear of furniture and walls and see at least 1.2 m of room ahead; its
    score counts the class objects whose amodal-box centre projects into the image at 0.5-7 m,
    plus a little noise so that equally good views are picked at random.
    """
    H, W = image_size
    room = layout.room
    rects = [p.footprint() for p in layout.objects if p.render and p.item.collides]
    centres = np.array(
        [
            [
                *p.to_room(*(0.5 * (p.item.lo + p.item.hi))[[0, 2]]),
                p.base + 0.5 * (p.item.lo[1] + p.item.hi[1]),
            ]
            for p in layout.objects
            if p.render and p.item.cls is not None
        ]
    ).reshape(-1, 3)
    best, best_score = None, -math.inf
    for _ in range(ranges.candidates):
        if rng.random() < 0.7:  # standing near a wall, looking into the room
            k = int(rng.integers(4))
            (x0, z0), (tx, tz), yaw, length = layout.wall(k)
            s, d = rng.uniform(0.25, length - 0.25), rng.uniform(0.25, 1.2)
            x, z = x0 + s * tx + d * math.sin(yaw), z0 + s * tz + d * math.cos(yaw)
            heading = yaw + rng.uniform(-1.0, 1.0)
            if not (0.25 <= x <= room.width - 0.25 and 0.25 <= z <= room.depth - 0.25):
                continue
        else:
            x, z = rng.uniform(0.25, room.width - 0.25), rng.uniform(0.25, room.depth - 0.25)
            heading = rng.uniform(0, 2 * math.pi)
        pose = CameraPose(
            float(x),
            float(z),
            float(rng.uniform(*ranges.height)),
            float(heading),
            math.radians(rng.uniform(*ranges.pitch_deg)),
            math.radians(rng.uniform(*ranges.roll_deg)),
        )
        score = float(rng.uniform(0, 0.5))
        if any(point_rect_distance(pose.x, pose.z, r) < ranges.clearance for r in rects):
            score -= 1000
        if _distance_to_wall(pose, room.width, room.depth) < 1.2:
            score -= 100
        if len(centres):
            cam = pose.room_to_tilt(centres[:, 0], centres[:, 2], centres[:, 1]) @ pose.R_tilt
            zc = cam[:, 2]
            ok = (zc > 0.5) & (zc < 7.0)
            u = K.fx * cam[:, 0] / np.where(ok, zc, 1.0) + K.cx
            v = K.fy * cam[:, 1] / np.where(ok, zc, 1.0) + K.cy
            score += float(np.sum(ok & (u > 0) & (u < W - 1) & (v > 0) & (v < H - 1)))
        if score > best_score:
            best, best_score = pose, score
    if best is None:  # only possible with no candidates at all
        raise ValueError("choose_camera: no candidate pose (ranges.candidates must be > 0)")
    return best


def _distance_to_wall(pose: CameraPose, width: float, depth: float) -> float:
    """Horizontal distance from the camera to the wall straight ahead."""
    dx, dz = math.sin(pose.heading), math.cos(pose.heading)
    ts = [
        t
        for t in (
            (width - pose.x) / dx if dx > 1e-9 else math.inf,
            -pose.x / dx if dx < -1e-9 else math.inf,
            (depth - pose.z) / dz if dz > 1e-9 else math.inf,
            -pose.z / dz if dz < -1e-9 else math.inf,
        )
    ]
    return min(ts)
