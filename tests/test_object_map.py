"""The object map: robust fusion (yaw modulo pi, the l/w symmetry), association gates, the map over
posed frames (support, misses, dropping, merging, a world that is not gravity-aligned) and
a3d-run --map."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.mapping.association import AssociationGates, associate
from a3d.runtime.mapping.fusion import fuse_boxes
from a3d.runtime.mapping.object_map import MapConfig, ObjectMap
from a3d.runtime.mapping.world import box_differences, boxes_to_camera, rtilt_from_pose
from a3d.runtime.structures.classes import class_index
from a3d.runtime.structures.geometry import Intrinsics, rtilt_from_pitch_roll
from a3d.runtime.structures.pose import make_pose
from a3d.synth.cli import main as synth_main
from tests.helpers.runtime_frames import FakeModel, write_scene_folder

K = Intrinsics(200.0, 200.0, 159.5, 119.5)
SIZE = (240, 320)
WORLD = np.array([[0.0, -0.45, 3.0, 0.6, 0.5, 0.9, 0.3], [1.5, -0.4, 3.5, 2.0, 1.0, 0.8, -0.2]])  # chair, bed
CLASSES = np.array([class_index("chair"), class_index("bed")])


def R_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def camera(i: int) -> np.ndarray:
    """Poses round the objects, 1.4 m up (y = -1.4), looking roughly at them."""
    heading = -0.25 + 0.05 * i
    return make_pose(R_y(heading) @ rtilt_from_pitch_roll(-0.25, 0.01 * i), [0.2 * i - 1.0, -1.4, -0.5])


def detections(
    i: int, camera_pose: np.ndarray, boxes: np.ndarray, classes: np.ndarray, scores, **changes
) -> FrameDetections:
    R_tilt = rtilt_from_pose(camera_pose)
    in_camera = boxes_to_camera(boxes, camera_pose, R_tilt)
    values = dict(
        frame=f"f{i:03d}",
        R_tilt=R_tilt,
        class_ids=np.asarray(classes),
        scores=np.asarray(scores, np.float64),
        boxes2d=np.zeros((len(boxes), 4)),
        boxes3d=in_camera,
        gravity="given",
        pose=camera_pose,
    )
    return FrameDetections(**{**values, **changes})


def noisy(rng: np.random.Generator, boxes: np.ndarray) -> np.ndarray:
    out = boxes.copy()
    out[:, :3] += rng.normal(0, 0.03, (len(boxes), 3))
    out[:, 3:6] *= np.exp(rng.normal(0, 0.05, (len(boxes), 3)))
    out[:, 6] += rng.normal(0, 0.05, len(boxes))
    return out


# ----------------------------------------------------------------------------- fusion


def test_fusion_averages_yaw_modulo_pi_with_the_l_w_symmetry() -> None:
    same_bed = np.array(
        [
            [0, 0, 0, 2.0, 1.0, 0.5, 0.1],
            [0, 0, 0, 1.0, 2.0, 0.5, 0.1 + np.pi / 2],
            [0, 0, 0, 2.0, 1.0, 0.5, 0.1 - np.pi],
        ]
    )
    np.testing.assert_allclose(fuse_boxes(same_bed, np.ones(3)), [0, 0, 0, 2.0, 1.0, 0.5, 0.1], atol=1e-12)
    across = np.array([[0, 0, 0, 2.0, 1.0, 0.5, 1.55], [0, 0, 0, 2.0, 1.0, 0.5, -1.55]])  # both near pi/2
    assert abs(abs(fuse_boxes(across, np.ones(2))[6]) - np.pi / 2) < 1e-9  # not 0, their plain mean


def test_fusion_is_robust_and_weighted_by_score() -> None:
    boxes = np.tile([1.0, 0.0, 2.0, 0.6, 0.5, 0.9, 0.0], (10, 1))
    boxes[:, 0] += np.linspace(-0.02, 0.02, 10)
    boxes[9, 0] = 5.0  # one far-off observation: a plain mean would put x at 1.4
    assert abs(fuse_boxes(boxes, np.ones(10))[0] - 1.0) < 0.01
    two = np.array([[0.0, 0, 2, 0.6, 0.5, 0.9, 0], [0.3, 0, 2, 0.6, 0.5, 0.9, 0]])
    assert fuse_boxes(two, np.array([0.9, 0.1]))[0] < 0.05


# ----------------------------------------------------------------------------- association


def test_association_needs_the_class_and_both_gates_and_is_one_to_one() -> None:
    objects = np.array(
        [[0, 0, 3, 0.6, 0.5, 0.9, 0], [0.5, 0, 3, 0.6, 0.5, 0.9, 0], [5, 0, 3, 0.6, 0.5, 0.9, 0]]
    )
    classes = np.array([1, 1, 2])
    dets = np.array(
        [[0.45, 0, 3, 0.6, 0.5, 0.9, 0], [0.05, 0, 3, 0.6, 0.5, 0.9, 0], [5, 0, 3, 0.6, 0.5, 0.9, 0]]
    )
    assert associate(dets, np.array([1, 1, 1]), objects, classes) == [
        (0, 1),
        (1, 0),
    ]  # the third: wrong class
    tight = AssociationGates(max_centre_m=0.04)
    assert associate(dets, np.array([1, 1, 2]), objects, classes, tight) == [(2, 2)]
    assert associate(dets[:1], np.array([1]), objects[:1], classes[:1], AssociationGates(min_iou=0.5)) == []
    assert associate(np.zeros((0, 7)), np.zeros(0), objects, classes) == []


# ----------------------------------------------------------------------------- the map


def test_map_fuses_noisy_detections_into_one_box_per_object() -> None:
    rng = np.random.default_rng(0)
    world_map = ObjectMap()
    for i in range(12):
        pose = camera(i)
        update = world_map.update(
            detections(i, pose, noisy(rng, WORLD), CLASSES, [0.9, 0.8]), intrinsics=K, image_size=SIZE
        )
        assert update.skipped == "" and len(update.matched) == (0 if i == 0 else 2)
    assert [o.cls for o in world_map.objects] == ["chair", "bed"]
    fused = np.array([o.box for o in world_map.objects])
    assert np.abs(fused[:, :3] - WORLD[:, :3]).max() < 0.04  # 12 observations with 3 cm noise
    assert box_differences(fused, WORLD).max() < 0.1
    chair = world_map.objects[0]
    assert (
        chair.support == 12 and chair.misses == 0 and chair.frames[0] == "f000" and chair.frames[-1] == "f011"
    )
    assert chair.score() == pytest.approx(0.9)

    # Projected back into a frame, the map is one fixed box per object, in that frame's camera.
    pose = camera(5)
    back = world_map.seen_from(detections(5, pose, WORLD, CLASSES, [0.9, 0.8]), K, SIZE)
    R_tilt = rtilt_from_pose(pose)
    np.testing.assert_allclose(back.boxes3d, boxes_to_camera(fused, pose, R_tilt), atol=1e-9)
    assert back.class_ids.tolist() == CLASSES.tolist() and back.scores == pytest.approx([0.9, 0.8])
    assert np.all(back.boxes2d[:, 2:] > back.boxes2d[:, :2])
    away = pose @ make_pose(R_y(math.pi), [0.0, 0.0, 0.0])  # the same camera turned round
    assert len(world_map.seen_from(detections(5, away, WORLD, CLASSES, [0.9, 0.8]), K, SIZE)) == 0


def test_a_spurious_detection_is_dropped_once_missed_where_it_should_be_seen(tmp_path: Path) -> None:
    world_map = ObjectMap(MapConfig(max_misses=3))
    ghost = np.array([[-0.5, -0.4, 2.5, 0.4, 0.4, 0.8, 0.0]])
    update = world_map.update(
        detections(0, camera(0), np.vstack([WORLD, ghost]), [*CLASSES, class_index("lamp")], [0.9, 0.8, 0.6]),
        intrinsics=K,
        image_size=SIZE,
    )
    ghost_id = update.created[2]
    dropped_at = None
    for i in range(1, 6):
        update = world_map.update(
            detections(i, camera(i), WORLD, CLASSES, [0.9, 0.8]), intrinsics=K, image_size=SIZE
        )
        assert ghost_id in update.missed or ghost_id not in [o.id for o in world_map.objects]
        if ghost_id in update.dropped:
            dropped_at = i
    assert dropped_at == 3 and [o.cls for o in world_map.objects] == ["chair", "bed"]
    # a frame without intrinsics cannot tell what it should have seen: nothing is missed
    assert world_map.update(detections(6, camera(6), WORLD[:1], CLASSES[:1], [0.9])).missed == ()
    # a bed missed where it should be seen is kept (confirmed) but its score decays
    update = world_map.update(
        detections(7, camera(7), WORLD[:1], CLASSES[:1], [0.9]), intrinsics=K, image_size=SIZE
    )
    bed = world_map.objects[1]
    assert update.missed == (bed.id,) and bed.score() == pytest.approx(0.8 * 6 / 7)
    # frames the map cannot place are counted, not mapped
    assert (
        world_map.update(detections(8, camera(8), WORLD, CLASSES, [0.9, 0.8], pose=None)).skipped == "no pose"
    )
    fallback = detections(9, camera(9), WORLD, CLASSES, [0.9, 0.8], gravity="fallback: camera axes (...)")
    assert world_map.update(fallback).skipped == "gravity fallback"
    world_map.write(tmp_path / "map.json")
    document = json.loads((tmp_path / "map.json").read_text())
    assert document["frames_mapped"] == 8 and document["frames_skipped"] == {
        "no pose": 1,
        "gravity fallback": 1,
    }
    assert document["dropped"] == 1 and [o["class"] for o in document["objects"]] == ["chair", "bed"]
    assert document["objects"][1]["misses"] == 1 and document["objects"][1]["confirmed"]


def test_two_objects_that_come_to_overlap_are_merged() -> None:
    world_map = ObjectMap()
    twice = np.vstack([WORLD[:1], WORLD[:1] + 0.05 * np.eye(7)[0]])  # one chair detected twice
    update = world_map.update(detections(0, camera(0), twice, CLASSES[[0, 0]], [0.9, 0.7]))
    assert len(update.created) == 2 and update.merged == (update.created[1],)
    chair = world_map.objects[0]
    assert len(world_map.objects) == 1 and chair.support == 1 and len(chair.observations) == 2
    assert 0.0 < chair.box[0] < 0.05


def test_a_world_that_is_not_gravity_aligned_is_turned_so_that_y_is_down() -> None:
    tilt = make_pose(rtilt_from_pitch_roll(0.3, -0.2), [0.5, 0.2, -0.1])  # the data set's world from a3d's
    world_map = ObjectMap()
    for i in range(4):
        pose = camera(i)
        result = detections(i, pose, WORLD, CLASSES, [0.9, 0.8])  # R_tilt from gravity, as estimated
        world_map.update(result, tilt @ pose)
    np.testing.assert_allclose(world_map.world_down, tilt[:3, :3] @ [0, 1, 0], atol=1e-12)
    fused = np.array([o.box for o in world_map.objects])
    np.testing.assert_allclose(fused[:, 3:6], WORLD[:, 3:6], atol=1e-9)  # sizes survive
    np.testing.assert_allclose(
        np.linalg.norm(fused[0, :3] - fused[1, :3]), np.linalg.norm(WORLD[0, :3] - WORLD[1, :3]), atol=1e-9
    )
    np.testing.assert_allclose(fused[:, 1], WORLD[:, 1] - WORLD[0, 1] + fused[0, 1], atol=1e-9)  # heights


# ----------------------------------------------------------------------------- a3d-run --map


@pytest.fixture
def fake_model(monkeypatch: pytest.MonkeyPatch) -> FakeModel:
    model = FakeModel()
    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: model)
    return model


def test_a3d_run_map_writes_the_map_and_tracks_unposed_sources(
    tmp_path: Path, fake_model: FakeModel, capsys
) -> None:
    assert synth_main([str(tmp_path / "seq"), "--sequence", "6", "--seed", "3", "--size", "96x128"]) == 0
    capsys.readouterr()
    out, map_path = tmp_path / "det.jsonl", tmp_path / "map.json"
    argv = [str(tmp_path / "seq" / "frames"), "--model", "fake.onnx", "--output", str(out), "--headless"]
    assert run_cli.main([*argv, "--map", str(map_path), "--score-threshold", "0.0"]) == 0
    document = json.loads(map_path.read_text())
    assert document["frames_mapped"] == 6 and document["map_from_world"] == np.eye(4).tolist()
    assert f"a3d-run: map: {len(document['objects'])} objects" in capsys.readouterr().err
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert all("pose" in line for line in lines)

    plain = write_scene_folder(tmp_path / "plain", ["a"])  # no poses: tracked (tests/test_tracked_poses.py)
    unposed = [str(plain), "--model", "fake.onnx", "--output", str(out), "--headless", "--map", str(map_path)]
    assert run_cli.main(unposed) == 0
    assert run_cli.TRACKING_NOTE in capsys.readouterr().err
    assert json.loads(map_path.read_text())["frames_mapped"] == 1
    with pytest.raises(SystemExit, match="2"):
        run_cli.main([*argv, "--map", "--resume"])


def test_a3d_run_map_logs_the_map_to_rerun_in_the_world(tmp_path: Path, fake_model: FakeModel) -> None:
    pytest.importorskip("rerun")
    from tests.rrd_reader import as_array, read_columns

    assert synth_main([str(tmp_path / "seq"), "--sequence", "5", "--seed", "3", "--size", "96x128"]) == 0
    frames, rrd, map_path = tmp_path / "seq" / "frames", tmp_path / "run.rrd", tmp_path / "map.json"
    argv = [str(frames), "--model", "fake.onnx", "--output", str(tmp_path / "det.jsonl"), "--headless"]
    assert run_cli.main([*argv, "--save", str(rrd), "--map", str(map_path), "--score-threshold", "0.0"]) == 0
    poses = [json.loads((frames / f"seq_{i:06d}.meta.json").read_text())["pose"] for i in range(5)]
    cameras = read_columns(rrd, "/map/camera")
    assert sorted(cameras) == [0, 1, 2, 3, 4]
    np.testing.assert_allclose(
        as_array(cameras[4]["Transform3D:translation"])[0], np.array(poses[4])[:3, 3], atol=1e-5
    )
    trajectory = read_columns(rrd, "/map/trajectory")
    np.testing.assert_allclose(
        as_array(trajectory[4]["LineStrips3D:strips"][0]), np.array(poses)[:, :3, 3], atol=1e-5
    )
    assert "Pinhole:image_from_camera" in read_columns(rrd, "/map/camera/frustum")[0]
    objects = read_columns(rrd, "/map/objects")[4]
    document = json.loads(map_path.read_text())
    np.testing.assert_allclose(
        as_array(objects["Boxes3D:centers"]), [o["centre"] for o in document["objects"]], atol=1e-5
    )
