"""Labels drawn once (a3d-labels): world boxes and posed frames -> each frame's ground truth, equal to
what a3d-synth renders for the same sequence; the seen-pixel count worked by hand; bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import labels as labels_cli
from a3d.runtime.mapping.labels import LabelConfig, label_frame
from a3d.runtime.mapping.world_boxes import WorldBoxes
from a3d.runtime.sources.folder import list_frames, read_ground_truth, read_instances
from a3d.runtime.structures.geometry import Intrinsics
from a3d.runtime.structures.pose import make_pose
from a3d.synth.cli import main as synth_main
from bench.label_propagation import compare


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sequence")
    assert synth_main([str(out), "--sequence", "16", "--seed", "11", "--size", "180x240"]) == 0
    return out


def test_propagated_labels_equal_the_rendered_ground_truth(sequence: Path, tmp_path: Path) -> None:
    world = sequence / "world_boxes.json"
    assert labels_cli.main([str(world), str(sequence / "frames"), "--out", str(tmp_path / "out")]) == 0
    result = compare(sequence, tmp_path / "out")
    assert result.frames == 16 and result.both >= 60
    assert result.box3d_max < 1e-6 and result.amodal_max < 1e-6
    assert result.agreement >= 0.98, result.disagreements
    assert result.visible_iou > 0.8
    ref = list_frames(tmp_path / "out")[3]
    truth, instances = read_ground_truth(ref), read_instances(ref)
    assert len(truth) and set(np.unique(instances)) <= set(range(len(truth) + 1))


def test_seen_pixels_of_a_box_on_the_floor_worked_by_hand() -> None:
    """A level camera 1 m above the floor (the world: y down, the camera at its origin) and a 1 m
    cube standing on the floor 3 to 4 m ahead: its front face's pixels are its seen pixels, less a
    hole in the depth; the floor around it is not (its bottom is raised by the floor gap), and a
    second cube behind a wall of depth at 20 m is in view but not seen."""
    K = Intrinsics(100.0, 100.0, 49.5, 49.5)
    v, u = np.indices((100, 100), dtype=np.float64)
    below = v > K.cy
    depth = np.full((100, 100), 20.0)
    depth[below] = np.minimum(K.fy * 1.0 / (v[below] - K.cy), 20.0)  # the floor, 1 m down
    face = (
        (np.abs(u - K.cx) <= 0.5 * K.fx / 3) & below & (v - K.cy <= 1.0 * K.fy / 3)
    )  # x in +-0.5, y in [0, 1]
    depth[face] = 3.0
    depth[50:55, 45:50] = 0.0  # a hole in the face
    depth = depth.astype(np.float32)
    boxes = np.array([[0.0, 0.5, 3.5, 1.0, 1.0, 1.0, 0.0], [0.0, 0.5, 25.0, 1.0, 1.0, 1.0, 0.0]])
    world = WorldBoxes(["box", "chair"], boxes, np.array([7, 8]))
    labels = label_frame(
        world, make_pose(np.eye(3), np.zeros(3)), np.eye(3), depth, K, LabelConfig(fill_holes=False)
    )
    assert labels.seen_px.tolist() == [34 * 33 - 25, 0]  # columns 33-66, rows 50-82, less the hole
    assert labels.ids.tolist() == [7] and labels.truth.classes == ["box"]
    assert labels.truth.boxes2d_visible[0].tolist() == [32.5, 49.5, 66.5, 82.5]
    assert labels.expected_px[0] == pytest.approx((100 / 3) ** 2, rel=1e-6)  # the front face hides the rest
    assert labels.expected_px[1] > 0 and labels.visibility[1] == 0.0
    np.testing.assert_array_equal(labels.truth.boxes3d[0], boxes[0])


def test_frames_without_pose_and_bad_world_boxes_are_one_line(sequence: Path, tmp_path: Path, capsys) -> None:
    frames = tmp_path / "frames"
    shutil.copytree(sequence / "frames", frames)
    meta = frames / "seq_000002.meta.json"
    document = json.loads(meta.read_text())
    del document["pose"]
    meta.write_text(json.dumps(document))
    world = sequence / "world_boxes.json"
    assert labels_cli.main([str(world), str(frames), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert f"a3d-labels: {frames / 'seq_000002.color.png'}: no pose; not labelled" in err
    assert len(list_frames(tmp_path / "out")) == 15
    (tmp_path / "bad.json").write_text('{"objects": [{"class": "chair"}]}')
    assert labels_cli.main([str(tmp_path / "bad.json"), str(frames), "--out", str(tmp_path / "out2")]) == 2
    message = f"a3d-labels: error: {tmp_path / 'bad.json'}: objects[0]: lacks 'centre' (keys: class, centre"
    assert capsys.readouterr().err.startswith(message)
    with pytest.raises(SystemExit, match="2"):
        labels_cli.main([str(world), str(frames), "--out", str(frames)])
    assert capsys.readouterr().err.endswith(
        "a3d-labels: error: --out must not be SOURCE (its frames would be overwritten)\n"
    )
