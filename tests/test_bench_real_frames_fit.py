"""bench/real_frames_fit.py: the object's cluster (the floor plane: tests/test_floor_contact.py), the
fitted box down to the floor for a floor class, the file format the committed 3D boxes keep, and
both modes on a tiny frame folder (the draft validates; the pictures are written, with a run's
detections drawn in their class colours over the truth's boxes where a detections file is given)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, class_index
from a3d.runtime.structures.geometry import box_corners_camera, rtilt_from_pitch_roll
from bench import real_frames_fit
from bench.real_frames import DEFAULT_BOXES3D, read_boxes, read_boxes3d
from bench.real_frames_fit import dump, fit_object, largest_cluster
from bench.real_frames_views import FrameCloud, found_boxes
from tests.helpers.point_layers import point_layer
from tests.helpers.runtime_frames import W, write_scene_folder

RNG = np.random.default_rng(0)


def test_the_object_is_the_largest_cluster_by_distance() -> None:
    chair = point_layer(RNG, 500, 0.8, (-0.2, 0.2), (2.0, 2.3))
    wall = point_layer(RNG, 300, 0.8, (-0.2, 0.2), (3.5, 3.6))
    assert (
        len(largest_cluster(np.vstack([wall, chair]))) == 500 and len(largest_cluster(np.zeros((0, 3)))) == 0
    )


@pytest.mark.parametrize(("name", "height"), [("chair", 0.9), ("box", 0.5)])
def test_a_floor_class_reaches_down_to_the_floor_and_another_does_not(name: str, height: float) -> None:
    cloud = FrameCloud(np.eye(3), np.zeros((1, 1, 3)), np.ones((1, 1), bool), np.array([0.0, 0.0, 1.4]))
    points = np.vstack([point_layer(RNG, 400, y, (0.0, 0.5), (2.0, 2.4)) for y in np.linspace(0.5, 1.0, 11)])
    box = fit_object(points, name, cloud)
    assert box[5] == pytest.approx(height, abs=0.02) and box[1] + box[5] / 2 == pytest.approx(
        0.5 + height, abs=0.02
    )
    assert sorted(box[3:5]) == pytest.approx([0.4, 0.5], abs=0.03)


def test_the_committed_3d_boxes_file_is_in_dump_s_one_object_a_line_form() -> None:
    text = DEFAULT_BOXES3D.read_text()
    assert dump(json.loads(text)) == text


def test_fit_writes_a_draft_that_validates_and_draw_writes_the_pictures(tmp_path: Path, capsys) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    hand = {"frames": {"a": {"objects": [{"class": "chair", "box": [0, 0, W, 40]}]}, "b": {"objects": []}}}
    boxes = tmp_path / "boxes.json"
    boxes.write_text(json.dumps(hand))
    draft = tmp_path / "draft.json"
    assert real_frames_fit.main([str(folder), "--fit", str(draft), "--boxes", str(boxes)]) == 0
    frames = read_boxes3d(draft, read_boxes(boxes))  # every object boxed or skipped, with a reason
    assert len(frames["a"].objects) + len(json.loads(draft.read_text())["frames"]["a"]["skipped"]) == 1
    out = tmp_path / "pictures"
    argv = [str(folder), "--draw", str(out), "--boxes", str(boxes), "--boxes3d", str(draft)]
    assert real_frames_fit.main(argv) == 0, capsys.readouterr().err
    assert cv2.imread(str(out / "real_frames_boxes3d.jpg")) is not None and (out / "a.png").is_file()
    assert len(list((out / "objects").glob("a_*.png"))) == len(frames["a"].objects)


def test_a_bad_boxes_file_stops_either_mode_with_one_line(tmp_path: Path, capsys) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    rc = real_frames_fit.main(
        [str(folder), "--fit", str(tmp_path / "d.json"), "--boxes", str(tmp_path / "no.json")]
    )
    err = capsys.readouterr().err.strip()
    assert (
        rc == 1 and err.startswith("real_frames_fit: ") and "no.json: cannot read" in err and "\n" not in err
    )


def _detections(frame: str, R_tilt: np.ndarray, scores: list[float]) -> FrameDetections:
    """A run's line: one monitor box a metre and a half ahead per score."""
    boxes = np.array([[0.1 * i, 0.0, 1.5, 0.4, 0.2, 0.3, 0.3] for i in range(len(scores))])
    ids = np.full(len(scores), class_index("monitor"))
    return FrameDetections(frame, R_tilt, ids, np.array(scores), np.zeros((len(scores), 4)), boxes)


def test_found_boxes_keep_the_threshold_and_meet_the_truth_in_its_tilt_frame() -> None:
    own, truth = rtilt_from_pitch_roll(0.2, -0.05), rtilt_from_pitch_roll(0.07, 0.03)
    found = found_boxes(_detections("a", own, [0.9, 0.3, 0.6]), 0.5, truth)
    kept = np.array([0, 2])
    camera = box_corners_camera(found.boxes3d, own)  # where the run puts its corners
    assert found.outlines.labels == ["monitor 0.90", "monitor 0.60"]
    np.testing.assert_allclose(found.outlines.corners, camera @ truth.T, atol=1e-9)
    np.testing.assert_array_equal(found.boxes3d, _detections("a", own, [0.9, 0.3, 0.6]).boxes3d[kept])


def test_draw_with_detections_draws_their_boxes_in_their_class_colour(tmp_path: Path, capsys) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    hand = {"frames": {"a": {"objects": [{"class": "chair", "box": [0, 0, W, 40]}]}}}
    boxes = tmp_path / "boxes.json"
    boxes.write_text(json.dumps(hand))
    draft = tmp_path / "draft.json"
    assert real_frames_fit.main([str(folder), "--fit", str(draft), "--boxes", str(boxes)]) == 0
    run = tmp_path / "detections.jsonl"
    pictures = {}
    for name, score in (("low", 0.4), ("high", 0.8)):
        write_detections(run, [_detections("a", np.eye(3), [score])])
        out = tmp_path / name
        argv = [str(folder), "--draw", str(out), "--boxes", str(boxes), "--boxes3d", str(draft)]
        assert real_frames_fit.main([*argv, "--detections", str(run)]) == 0, capsys.readouterr().err
        assert cv2.imread(str(out / "detections_boxes3d.jpg")) is not None
        pictures[name] = cv2.imread(str(out / "a.png"))
    monitor = np.array(CLASS_COLORS_RGB[class_index("monitor")][::-1])
    coloured = {k: int((np.abs(v.astype(int) - monitor).sum(axis=2) < 30).sum()) for k, v in pictures.items()}
    assert coloured["low"] < 5 < coloured["high"]  # drawn at 0.8, not at 0.4 under the threshold 0.5
