"""bench.box_errors: which part of a detection's 3D box loses its object."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from a3d.runtime.evaluation.metric import FrameTruth
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.synth.cli import main as synth_main
from bench.box_errors import box_errors, main, map_as_placed, placed, read


def test_a_box_moved_along_its_ray_is_lost_by_its_place_alone(tmp_path: Path, capsys) -> None:
    assert synth_main([str(tmp_path / "seq"), "--sequence", "3", "--seed", "3", "--size", "240x320"]) == 0
    frames = tmp_path / "seq" / "frames"
    truth, _ = load_truth(frames)
    lines, shifts_made = [], []
    for name, frame in truth.items():  # each object detected 3/4 of its width further along the camera's ray
        R = np.asarray(frame.R_tilt, np.float64)
        boxes = np.array(frame.boxes3d, np.float64)
        centres = boxes[:, :3] @ R.T  # tilt frame
        ray = centres[:, [0, 2]] / np.linalg.norm(centres[:, [0, 2]], axis=1, keepdims=True)
        shifts = 0.75 * boxes[:, 3:5].min(axis=1)
        centres[:, [0, 2]] += shifts[:, None] * ray
        shifts_made.extend(shifts)
        boxes[:, :3] = centres @ R
        n = len(boxes)
        lines.append(FrameDetections(name, R, np.asarray(frame.class_ids), np.full(n, 0.9),
                                     np.tile([0.0, 0.0, 10.0, 10.0], (n, 1)), boxes))  # fmt: skip
    write_detections(tmp_path / "moved.jsonl", lines)
    read_back = read(frames, tmp_path / "moved.jsonl")
    counts = box_errors(*read_back)
    objects = sum(c["objects"] for c in counts.values())
    assert objects == sum(len(frame.class_ids) for frame in truth.values()) > 0
    assert sum(c["fixed"]["across the floor"] for c in counts.values()) == objects
    assert sum(c["found"] for c in counts.values()) < objects  # 3/4 of its width off loses most
    for c in counts.values():  # the other parts are the truth's already: fixing them finds no more
        assert c["fixed"]["height"] == c["fixed"]["size"] == c["fixed"]["yaw"] == c["found"]
        assert len(c["missed"]) == c["objects"] - c["found"]
    missed = [row for c in counts.values() for row in c["missed"]]
    assert missed and all(abs(across) < 1e-6 for _, across, _ in missed)
    assert all(np.abs(np.array(shifts_made) - along).min() < 1e-6 for along, _, _ in missed)  # further: > 0
    written, moved_back = map_as_placed(*read_back)
    assert written < 0.5 < 0.9 < moved_back  # (a moved box may stand nearer a neighbour of its class)
    capsys.readouterr()
    assert main([str(frames), "--detections", str(tmp_path / "moved.jsonl")]) == 0
    out = capsys.readouterr().out
    assert (
        "| with the truth's across the floor |" in out
        and f"{100 * moved_back:.1f} with every detection" in out
    )


def test_placed_moves_a_box_across_the_floor_to_its_class_s_nearest_object_within_reach() -> None:
    pitch = np.radians(20)
    R = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    chair, table = (
        np.array([0.5, 0.4, 2.0, 0.6, 0.5, 0.9, 0.3]),
        np.array([-1.0, 0.5, 3.0, 1.2, 0.8, 0.7, 0.0]),
    )
    truth = FrameTruth(np.array([4, 16]), np.stack([chair, table]), R)  # a chair and a table
    off = chair.copy()  # 0.5 m off across the floor, 5 cm in height
    off[:3] = R.T @ (R @ chair[:3] + np.array([0.3, 0.05, -0.4]))
    far = table.copy()
    far[:3] = R.T @ (R @ table[:3] + np.array([1.5, 0.0, 0.0]))  # beyond the reach
    sofa = chair.copy()  # of a class no object has
    line = FrameDetections(
        "f", R, np.array([4, 16, 15]), np.ones(3), np.zeros((3, 4)), np.stack([off, far, sofa])
    )
    moved = placed(truth, line).boxes3d
    expected = chair.copy()
    expected[:3] = R.T @ (R @ chair[:3] + np.array([0.0, 0.05, 0.0]))  # its own height kept
    np.testing.assert_allclose(moved[0], expected, atol=1e-9)
    np.testing.assert_allclose(moved[1:], np.stack([far, sofa]), atol=1e-9)
