"""The rerun view logs what a3d computed: read the .rrd back and compare values."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
import rerun as rr

from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import (
    NYU_CROP_INTRINSICS,
    box_corners_camera,
    project_points,
    rtilt_from_pitch_roll,
)
from a3d.runtime.viewer import options as viewer_options
from a3d.runtime.viewer import shapes
from a3d.runtime.viewer import view as viewer
from tests.rrd_reader import as_array, entity_paths, read_columns

K = NYU_CROP_INTRINSICS
H, W = 427, 561


def _frame(rng: np.random.Generator) -> dict:
    boxes3d = np.array([[0.3, 0.4, 3.0, 1.2, 0.6, 0.8, 0.4], [-0.8, 0.2, 4.5, 0.5, 0.5, 0.9, -1.1]])
    return dict(
        color=rng.integers(0, 255, (H, W, 3), dtype=np.uint8),
        depth_m=rng.uniform(0.5, 6.0, (H, W)).astype(np.float32),
        K=K,
        R_tilt=rtilt_from_pitch_roll(np.radians(-20.0), np.radians(3.0)),
        class_ids=np.array([4, 16]),
        scores=np.array([0.9, 0.55]),
        boxes2d=np.array([[10.5, 20.5, 100.5, 200.5], [300.0, 50.0, 400.0, 250.0]]),
        boxes3d=boxes3d,
    )


def _record(path: Path, frames: list[dict]) -> None:
    args = argparse.Namespace(
        headless=True, connect=False, serve=False, url=None, save=str(path), stdout=False
    )
    rec = viewer.open_recording(args)
    rr.set_strict_mode(True)
    viewer.log_static(rec)
    for i, frame in enumerate(frames):
        viewer.log_frame(rec, i, **frame)
    rec.flush()
    rr.disconnect(rec)


def test_logged_boxes_read_back_equal(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    frames = [_frame(rng), _frame(rng)]
    frames[1]["boxes3d"] = frames[1]["boxes3d"] + [0.1, 0.0, 0.2, 0, 0, 0, 0.1]
    path = tmp_path / "run.rrd"
    _record(path, frames)

    boxes3d = read_columns(path, "/world/detections")
    boxes2d = read_columns(path, "/world/camera/image/detections")
    assert sorted(boxes3d) == [0, 1]
    for i, frame in enumerate(frames):
        logged = boxes3d[i]
        R = frame["R_tilt"]
        b = frame["boxes3d"]
        np.testing.assert_allclose(as_array(logged["Boxes3D:centers"]), b[:, :3] @ R.T, atol=1e-5)
        np.testing.assert_allclose(as_array(logged["Boxes3D:half_sizes"]), b[:, [3, 5, 4]] / 2, atol=1e-6)
        angles = [r["angle"] for r in logged["Boxes3D:rotation_axis_angles"]]
        np.testing.assert_allclose(angles, b[:, 6], atol=1e-6)
        assert logged["Boxes3D:class_ids"] == [5, 17]
        assert logged["Boxes3D:labels"] == ["chair 0.90", "table 0.55"]
        centres = as_array(boxes2d[i]["Boxes2D:centers"])
        np.testing.assert_allclose(
            centres, (frame["boxes2d"][:, :2] + frame["boxes2d"][:, 2:]) / 2, atol=1e-5
        )


def _camera_view_labels(path: Path, frame: int) -> list[str]:
    """The labels rerun writes in the camera view at ``frame``: those of every entity under the
    image but the depth (the blueprint's contents), or, for an entity with class ids and no labels,
    the class names of the annotation context; none where show_labels is false."""
    shown = []
    for entity in sorted(entity_paths(path)):
        if not entity.startswith("/world/camera/image/") or entity.endswith("/depth"):
            continue
        columns = {name.split(":")[1]: v for name, v in read_columns(path, entity).get(frame, {}).items()}
        if columns.get("show_labels") == [False]:
            continue
        shown += columns.get("labels") or [CLASSES[i - 1] for i in columns.get("class_ids", [])]
    return shown


def test_camera_view_writes_one_label_per_detection_with_its_score(tmp_path: Path) -> None:
    """Not one per 2D box and one per projected edge: one "class score", at the top of the 2D box."""
    frame = _frame(np.random.default_rng(6))
    path = tmp_path / "labels.rrd"
    _record(path, [frame])
    assert sorted(_camera_view_labels(path, 0)) == ["chair 0.90", "table 0.55"]
    anchors = as_array(read_columns(path, "/world/camera/image/labels")[0]["Points2D:positions"])
    boxes = frame["boxes2d"]
    np.testing.assert_allclose(anchors, np.c_[(boxes[:, 0] + boxes[:, 2]) / 2, boxes[:, 1]], atol=1e-5)
    edges = read_columns(path, "/world/camera/image/boxes3d")[0]
    assert len(edges["LineStrips2D:strips"]) > 2  # the projected boxes are drawn, their edges unlabelled


def test_logged_box_pose_reproduces_the_corners() -> None:
    """Rebuild the corners from what Boxes3D holds (world frame) and compare with geometry's."""
    frame = _frame(np.random.default_rng(1))
    R = frame["R_tilt"]
    arche = viewer.boxes3d_archetype(frame["boxes3d"], R, frame["class_ids"], ["a", "b"])
    centres = arche.centers.as_arrow_array().to_numpy(zero_copy_only=False)
    centres = np.stack(centres) if centres.dtype == object else centres.reshape(-1, 3)
    half = np.asarray(arche.half_sizes.as_arrow_array().to_pylist())
    theta = frame["boxes3d"][:, 6]
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    for k in range(2):
        c, s = np.cos(theta[k]), np.sin(theta[k])
        Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        world = np.asarray(centres[k]) + (signs * half[k]) @ Ry.T
        expected = box_corners_camera(frame["boxes3d"][k : k + 1], R)[0] @ R.T
        assert np.allclose(np.sort(world, axis=0), np.sort(expected, axis=0), atol=1e-5)


def test_projected_edges_match_projected_corners_and_clip_behind_camera() -> None:
    frame = _frame(np.random.default_rng(2))
    R = frame["R_tilt"]
    seg = shapes.projected_box_edges(frame["boxes3d"], R, K)
    assert seg.shape == (24, 2, 2)
    corners_uv = project_points(box_corners_camera(frame["boxes3d"], R), K).reshape(-1, 2)
    # In front of the camera nothing is clipped: every segment end is a projected corner.
    ends = seg.reshape(-1, 2)
    d = np.linalg.norm(ends[:, None, :] - corners_uv[None], axis=-1).min(axis=1)
    assert d.max() < 1e-6

    straddling = np.array([[0.0, 0.0, 0.3, 2.0, 1.0, 1.0, 0.0]])  # extends from z=-0.2 to 0.8
    seg = shapes.projected_box_edges(straddling, np.eye(3), K)
    finite = np.isfinite(seg).all(axis=(1, 2))
    # The back face (4 edges at z = -0.2) is dropped; the 4 side edges are cut at the near plane.
    assert finite.sum() == 8
    assert (np.abs(seg[finite]) < 1e5).all()
    behind = np.array([[0.0, 0.0, -3.0, 1.0, 1.0, 1.0, 0.0]])
    assert np.isnan(shapes.projected_box_edges(behind, np.eye(3), K)).all()


def test_headless_without_sink_logs_nothing() -> None:
    none = argparse.Namespace(headless=True, connect=False, serve=False, url=None, save=None, stdout=False)
    assert not viewer_options.viewer_requested(none)
    assert viewer_options.viewer_requested(argparse.Namespace(**{**vars(none), "save": "x.rrd"}))


def test_clip_segments_known_answers() -> None:
    size = (101, 201)  # image spans x in [-0.5, 200.5], y in [-0.5, 100.5]
    seg = np.array(
        [
            [[10.0, 10.0], [20.0, 30.0]],  # inside: unchanged
            [[-100.5, 50.0], [99.5, 50.0]],  # enters at the left border, halfway along
            [[100.0, 50.0], [100.0, 400.5]],  # leaves at the bottom
            [[-50.0, -50.0], [-10.0, 300.0]],  # wholly left of the image
            [[-50.0, 10.0], [-50.0, 60.0]],  # vertical, wholly left: no inf * 0 warning
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = shapes.clip_segments(seg, size)
    np.testing.assert_allclose(out[0], seg[0])
    np.testing.assert_allclose(out[1], [[-0.5, 50.0], [99.5, 50.0]])
    np.testing.assert_allclose(out[2], [[100.0, 50.0], [100.0, 100.5]])
    assert np.isnan(out[3]).all() and np.isnan(out[4]).all()


def test_edges_clipped_to_the_image_stay_inside_it() -> None:
    frame = _frame(np.random.default_rng(3))
    big = np.array([[0.0, 0.0, 1.5, 6.0, 4.0, 3.0, 0.3]])  # much larger than the field of view
    seg = shapes.projected_box_edges(big, frame["R_tilt"], K, (H, W))
    finite = seg[np.isfinite(seg).all(axis=(1, 2))]
    assert len(finite) > 0
    assert finite[..., 0].min() >= -0.5 - 1e-9 and finite[..., 0].max() <= W - 0.5 + 1e-9
    assert finite[..., 1].min() >= -0.5 - 1e-9 and finite[..., 1].max() <= H - 0.5 + 1e-9


def test_low_scores_are_not_drawn_and_ground_truth_is_labelled(tmp_path: Path) -> None:
    frame = _frame(np.random.default_rng(4))
    path = tmp_path / "cut.rrd"
    args = argparse.Namespace(
        headless=True, connect=False, serve=False, url=None, save=str(path), stdout=False
    )
    rec = viewer.open_recording(args)
    viewer.log_static(rec)
    viewer.log_frame(
        rec,
        0,
        **frame,
        gt_class_ids=np.array([4]),
        gt_boxes3d=frame["boxes3d"][:1],
        options=shapes.ViewOptions(min_score=0.6),
    )
    rec.flush()
    rr.disconnect(rec)
    logged = read_columns(path, "/world/detections")[0]
    assert logged["Boxes3D:labels"] == ["chair 0.90"]  # the 0.55 table is below the display cut
    gt = read_columns(path, "/world/ground_truth")[0]
    assert gt["Boxes3D:labels"] == ["GT chair"]


def test_save_creates_the_recordings_folder(tmp_path: Path) -> None:
    path = tmp_path / "new" / "folder" / "run.rrd"
    _record(path, [_frame(np.random.default_rng(5))])
    assert read_columns(path, "/world/detections")[0]["Boxes3D:class_ids"] == [5, 17]
