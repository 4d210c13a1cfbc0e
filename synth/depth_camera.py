"""A synthetic frame's depth as a second camera beside the colour camera sees it.

Real RGB-D devices measure depth with their own camera, centimetres from the colour camera, and
many recordings keep it that way (unregistered). ``render_depth_from`` renders the exact
z-depth of frame ``seed``'s scene from such a depth camera, so registration
(``a3d.runtime.frontend.registration``) can be checked against the depth rendered in the
colour camera itself (``SynthFrame.depth_exact``). The scene is rebuilt from the seed exactly as
``generate_frame`` builds it (same random draws in the same order), then only ray-cast.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.frontend.registration import DepthToColor
from a3d.runtime.structures.geometry import Intrinsics
from a3d.synth.camera import choose_camera
from a3d.synth.cli import scaled_intrinsics
from a3d.synth.raycast import RayGrid, cast, room_exit
from a3d.synth.scene import SceneConfig, build_parts
from a3d.synth.world import furnish_world


def render_depth_from(
    seed: int, config: SceneConfig, calibration: DepthToColor, size: tuple[int, int]
) -> np.ndarray:
    """(h, w) float32 exact z-depth (metres, 0 = nothing) of frame ``seed`` seen by the depth
    camera of ``calibration`` (its intrinsics; ``p_color = R p_depth + t``), image ``size``."""
    rng = np.random.default_rng(seed)
    _, layout = furnish_world(rng, config.room_type, config.clutter, config.labelled)
    pose = choose_camera(layout, rng, config.camera, config.intrinsics, config.image_size)
    placed = [p for p in layout.objects if p.render]
    parts, _, _ = build_parts(placed, pose, rng, config)
    R_tilt = pose.R_tilt  # p_tilt = R_tilt p_color
    grid = RayGrid.make(
        R_tilt @ calibration.t, R_tilt @ calibration.R, calibration.depth_intrinsics.matrix(), size
    )
    room = layout.room
    centre = pose.room_to_tilt(np.array(room.width / 2), np.array(room.height / 2), np.array(room.depth / 2))
    half = np.array([room.width / 2, room.height / 2, room.depth / 2])
    t = cast(grid, parts, len(placed), t=room_exit(grid, half, centre, -pose.heading)).t
    return np.where(np.isfinite(t), t, 0.0).astype(np.float32)


def offset_depth_camera(size: tuple[int, int]) -> tuple[DepthToColor, tuple[int, int]]:
    """A depth camera for colour images of ``size`` (H, W) at a3d-synth's scaled NYUv2
    intrinsics: 5 cm beside the colour camera (and 5 mm below, 2 mm ahead), turned 2 degrees
    about the vertical, with 1.5 times its resolution and a 15 % wider view (like a RealSense
    D435, whose depth camera sees more than its colour camera), so that it covers the colour
    image; its calibration and depth image size."""
    h, w = round(size[0] * 1.5), round(size[1] * 1.5)
    f = 1.5 * scaled_intrinsics(size).fx / 1.15
    a = np.radians(2.0)
    turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return DepthToColor(Intrinsics(f, f, w / 2 - 0.5, h / 2 - 0.5), turn, np.array([0.05, 0.005, 0.002])), (
        h,
        w,
    )
