"""a3d-synth --sequence: one static room, a moving camera, rigid poses in a gravity-aligned world,
and per-frame ground truth that is the world boxes moved into each camera."""

from __future__ import annotations

import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.mapping.world import boxes_to_camera, rtilt_from_pose, same_boxes
from a3d.runtime.mapping.world_boxes import read_world_boxes
from a3d.runtime.sources.folder import FolderSource, read_ground_truth
from a3d.runtime.structures.geometry import project_boxes_to_2d
from a3d.runtime.structures.pose import check_pose
from a3d.synth.camera import CameraPose
from a3d.synth.cli import main as synth_main
from a3d.synth.cli import scaled_intrinsics
from a3d.synth.devices import DEVICES
from a3d.synth.scene import SceneConfig, _moved_lights, generate_frame
from a3d.synth.sequence import WALL_MARGIN, orbit, room_of, world_pose
from a3d.synth.shading import Lights

SIZE = (120, 160)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sequence")
    assert synth_main([str(out), "--sequence", "10", "--seed", "3", "--size", "120x160"]) == 0
    return out


def test_poses_are_rigid_and_agree_with_each_frame_s_gravity(sequence: Path) -> None:
    source = FolderSource(sequence / "frames")
    assert len(source) == 10
    positions = []
    for ref in source.refs:
        meta = json.loads(ref.meta_path.read_text())
        pose = np.array(meta["pose"])
        np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(pose[:3, :3]), 1.0, atol=1e-12)
        np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])
        np.testing.assert_allclose(check_pose(pose, "pose"), pose, atol=1e-12)
        np.testing.assert_allclose(rtilt_from_pose(pose), meta["R_tilt"], atol=1e-12)
        positions.append(pose[:3, 3])
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    assert (steps > 0.1).all() and (steps < 1.5).all()  # the camera moves, a step at a time


def test_ground_truth_is_the_world_boxes_moved_into_each_camera(sequence: Path) -> None:
    world = read_world_boxes(sequence / "world_boxes.json")
    assert len(world) >= 8
    matched = 0
    for ref in FolderSource(sequence / "frames").refs:
        meta = json.loads(ref.meta_path.read_text())
        R_tilt, pose = np.array(meta["R_tilt"]), np.array(meta["pose"])
        gt = read_ground_truth(ref)
        in_camera = boxes_to_camera(world.boxes, pose, R_tilt)
        for name, box, amodal in zip(gt.classes, gt.boxes3d, gt.boxes2d_amodal, strict=True):
            k = int(same_boxes(box, in_camera, tolerance=1e-6)[0])
            assert k >= 0 and world.classes[k] == name
            expected = project_boxes_to_2d(in_camera[k : k + 1], R_tilt, scaled_intrinsics(SIZE), SIZE)[0]
            np.testing.assert_allclose(amodal, expected, atol=1e-6)
            matched += 1
    assert matched >= 30


def test_the_room_stays_and_only_the_camera_moves() -> None:
    config = replace(SceneConfig(), image_size=SIZE, intrinsics=scaled_intrinsics(SIZE))
    _, layout = room_of(3, config)
    poses = orbit(layout, 4)
    a = generate_frame(3, config, camera=poses[0], noise_seed=1)
    b = generate_frame(3, config, camera=poses[0], noise_seed=2)
    assert a.room_type == b.room_type
    np.testing.assert_array_equal(a.depth_exact, b.depth_exact)  # the same view ...
    assert not np.array_equal(a.depth, b.depth)  # ... with its own sensor noise
    np.testing.assert_array_equal(generate_frame(3, config).color, generate_frame(3, config).color)
    room = layout.room
    for pose in poses:  # inside the room, looking at its centre within the heading's swing
        assert 0.4 < pose.x < room.width - 0.4 and 0.4 < pose.z < room.depth - 0.4
        to_centre = np.arctan2(room.width / 2 - pose.x, room.depth / 2 - pose.z)
        assert abs((pose.heading - to_centre + np.pi) % (2 * np.pi) - np.pi) <= 0.15 + 1e-9
        np.testing.assert_allclose(world_pose(pose)[:3, 3], [pose.x, -pose.height, pose.z])


def test_lights_stay_where_they_are_in_the_room() -> None:
    old = CameraPose(1.0, 2.0, 1.5, 0.3, -0.2, 0.05)
    new = CameraPose(3.0, 0.5, 1.2, 2.5, -0.3, -0.02)
    lights = Lights(
        np.ones(3),
        np.array([[0.5, -1.2, 2.0], [1.0, -1.0, 3.0]]),
        np.ones((2, 3)),
        np.array([0.0, 1.0, 0.0]),
        np.ones(3),
    )
    moved = _moved_lights(lights, old, new)
    np.testing.assert_allclose(
        new.tilt_to_room(moved.positions), old.tilt_to_room(lights.positions), atol=1e-12
    )
    np.testing.assert_allclose(moved.sun_dir, [0.0, 1.0, 0.0], atol=1e-12)  # straight down stays down


def test_a_sequence_seen_by_one_camera_preset(tmp_path: Path) -> None:
    """``--camera-mix NAME`` with ``--sequence``: every frame of the preset's size, its intrinsics in
    the folder's intrinsics.json; two presets are refused (one camera)."""
    out = tmp_path / "rs"
    args = ["--sequence", "3", "--seed", "3", "--camera-mix", "realsense-d435", "--camera-scale", "0.25"]
    assert synth_main([str(out), *args]) == 0
    size, K = DEVICES["realsense-d435"].frame(0.25)
    source = FolderSource(out / "frames")
    assert len(source) == 3
    for frame in (loader.load() for loader in source):
        assert frame.depth.shape == size and frame.color.shape[:2] == size
    intrinsics = json.loads((out / "frames" / "intrinsics.json").read_text())
    assert intrinsics["fx"] == pytest.approx(K.fx) and intrinsics["cx"] == pytest.approx(K.cx)
    with pytest.raises(SystemExit) as refused:
        synth_main([str(tmp_path / "two"), *args[:-3], "realsense-d435,kinect-v1"])
    assert refused.value.code == 2 and not (tmp_path / "two").exists()


def test_two_loops_the_hand_held_one_and_then_a_robot_s() -> None:
    """``orbit(..., loops=2)``: the first half is the one-loop orbit of its frames, the second a
    lower loop the other way round on another path, none of its views a first-loop one again."""
    config = replace(SceneConfig(), image_size=SIZE, intrinsics=scaled_intrinsics(SIZE))
    _, layout = room_of(3, config)
    hand, both = orbit(layout, 6), orbit(layout, 12, loops=2)
    assert both[:6] == hand
    robot = both[6:]
    assert np.mean([p.height for p in robot]) < np.mean([p.height for p in hand]) - 0.3  # lower
    room = layout.room
    cx, cz = room.width / 2, room.depth / 2
    turns = [np.arctan2(p.x - cx, p.z - cz) for p in robot]
    assert all((b - a) % (2 * np.pi) > np.pi for a, b in itertools.pairwise(turns))  # the other way round
    half_x, half_z = cx - WALL_MARGIN, cz - WALL_MARGIN
    def path_scales(loop: list[CameraPose]) -> set[float]:
        return {round(float(np.hypot((p.x - cx) / half_x, (p.z - cz) / half_z)), 6) for p in loop}

    scales = [path_scales(hand), path_scales(robot)]
    assert all(len(s) == 1 for s in scales) and scales[0] != scales[1]  # each loop one ellipse, another path
    for loops, frames in ((3, 6), (2, 1)):
        with pytest.raises(ValueError, match="loops"):
            orbit(layout, frames, loops=loops)


def test_each_loop_s_height_given_a_robot_recording_its_own_room(tmp_path: Path) -> None:
    """``heights``: a robot's own two loops (``1.0,1.0``) keep the default's paths and turns, the
    first loop at the robot's height; a camera under a metre looks down less in proportion; a height
    per loop, each within HEIGHT_RANGE_M, or ValueError (and a3d-synth exits 2, writing nothing)."""
    config = replace(SceneConfig(), image_size=SIZE, intrinsics=scaled_intrinsics(SIZE))
    _, layout = room_of(3, config)
    default, robot, low = (orbit(layout, 12, 2, h) for h in (None, (1.0, 1.0), (0.5, 0.5)))
    assert [(p.x, p.z, p.heading) for p in robot] == [(p.x, p.z, p.heading) for p in default]
    assert robot[6:] == default[6:]  # the second loop was the robot's already
    assert np.mean([p.height for p in robot[:6]]) == pytest.approx(np.mean([p.height for p in default[6:]]))
    pitch = [np.mean([p.pitch for p in loop]) for loop in (robot, low)]
    assert pitch[0] < pitch[1] < 0 and pitch[1] == pytest.approx(pitch[0] / 2)
    for loops, heights in ((2, (1.0,)), (1, (0.1,)), (1, (2.5,))):
        with pytest.raises(ValueError, match="heights"):
            orbit(layout, 12, loops, heights)
    with pytest.raises(SystemExit) as refused:
        synth_main([str(tmp_path / "bad"), "--sequence", "4", "--loops", "2", "--heights", "1.0"])
    assert refused.value.code == 2 and not (tmp_path / "bad").exists()
