"""Boxes that can exist: whatever the network outputs, no written box has its centre at or behind
the camera or a non-positive size, and what was clamped that a user sees is counted in the line's
notes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from a3d.runtime.frontend.working_size import WorkingFrame
from a3d.runtime.io.detections_io import FrameDetections, format_line, parse_line
from a3d.runtime.pipeline import NetworkOutput, PipelineConfig, PreparedFrame, finish
from a3d.runtime.postprocess.box_limits import CLASS_MAX_SIZE_M, MIN_SIZE_M, bound_boxes, near_range
from a3d.runtime.structures.classes import NUM_CLASSES, NUM_OUTPUTS, class_index
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS

N_ROIS = 6
deltas = st.floats(-50.0, 50.0, allow_nan=False, width=32)


def _prepared(depth: np.ndarray, centers: np.ndarray, boxes: np.ndarray) -> PreparedFrame:
    frame = Frame("f", np.zeros((*depth.shape, 3), np.uint8), depth, NYU_CROP_INTRINSICS, origin="f")
    empty = np.zeros((0,), np.float32)
    return PreparedFrame(
        frame, WorkingFrame(frame), np.eye(3), boxes, centers, empty, empty, empty, empty, {}, "estimated", []
    )


@settings(max_examples=60, deadline=None)
@given(
    probs=arrays(np.float64, (N_ROIS, NUM_OUTPUTS), elements=st.floats(0.0, 1.0)),
    deltas3d=arrays(np.float64, (N_ROIS, NUM_OUTPUTS, 7), elements=deltas),
    deltas2d=arrays(np.float64, (N_ROIS, NUM_OUTPUTS, 4), elements=st.floats(-5.0, 5.0)),
    centers=arrays(np.float64, (N_ROIS, 3), elements=st.floats(-3.0, 8.0)),
    near=st.floats(0.0, 3.0),
    sparse=st.booleans(),
)
def test_no_written_box_is_behind_the_camera_or_empty(
    probs, deltas3d, deltas2d, centers, near, sparse
) -> None:
    """Random network outputs and lifted centres (some behind the camera), on clean and sparse
    depth: every written box has z >= the frame's near range > 0, sizes in (0, family bound]."""
    depth = np.full((48, 64), 0.0 if near == 0.0 else near + 0.5, np.float32)
    if sparse:
        depth[np.random.default_rng(0).random(depth.shape) < 0.9] = 0
    depth[0, 0] = near  # the nearest valid pixel, when near > 0
    boxes = np.tile(np.array([[4.0, 4.0, 30.0, 30.0]]), (N_ROIS, 1)) + np.arange(N_ROIS)[:, None]
    config = PipelineConfig(mean_sizes=np.full((NUM_CLASSES, 3), 0.8), top_k=5, min_score=0.0)
    det = finish(_prepared(depth, centers, boxes), NetworkOutput(probs, deltas3d, deltas2d), config)
    line = parse_line(format_line(det), "line")  # what a reader gets back
    assert (line.boxes3d[:, 2] >= near_range(depth) - 1e-6).all() and (line.boxes3d[:, 2] > 0).all()
    assert (line.boxes3d[:, 3:6] > 0).all()
    assert (line.boxes3d[:, 3:6] <= CLASS_MAX_SIZE_M[line.class_ids][:, None] + 1e-6).all()


def test_clamps_are_counted_and_slide_along_the_ray() -> None:
    chair, bed = class_index("chair"), class_index("bed")
    boxes = np.array(
        [
            [0.5, 0.2, 0.5, 0.6, 0.5, 0.9, 0.0],  # centre nearer than the near range (1 m): slides
            [0.1, 0.1, -2.0, 0.6, 0.5, 0.9, 0.0],  # behind the camera: z set to the near range
            [0.0, 0.0, 3.0, 9.0, 0.001, 1.0, 0.0],  # a 9 m chair, 1 mm wide
            [0.0, 0.0, 3.0, 5.0, 2.0, 1.0, 0.0],  # a 5 m bed is within the large family's bound
        ]
    )
    bounded = bound_boxes(boxes, np.array([chair, chair, chair, bed]), near_m=1.0)
    np.testing.assert_allclose(bounded.boxes3d[0, :3], [1.0, 0.4, 1.0])
    np.testing.assert_allclose(bounded.boxes3d[1, :3], [0.1, 0.1, 1.0])
    np.testing.assert_allclose(bounded.boxes3d[2, 3:6], [2.5, MIN_SIZE_M, 1.0])
    np.testing.assert_array_equal(bounded.boxes3d[3], boxes[3])
    assert (bounded.centres_clamped, bounded.sizes_clamped) == (2, 1)
    assert bounded.notes(np.array([0.9, 0.5, 0.01, 0.8])) == [
        "2 box centres scoring >= 0.5 clamped to the near range of the depth",
        "1 boxes with a size clamped to their class family's bounds",
    ]
    # A clamped centre of a detection nobody is shown (the tail below 0.5) is routine, no note;
    # a clamped size always is one.
    assert bounded.notes(np.array([0.4, 0.001, 0.01, 0.8])) == [
        "1 boxes with a size clamped to their class family's bounds"
    ]


def test_line_carries_gravity_and_notes_and_old_lines_stay_readable() -> None:
    det = FrameDetections(
        "f", np.eye(3), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 4)), np.zeros((0, 7)),
        gravity="fallback: camera axes (raw depth: too few surface normals)", notes=("no proposals: x",),
    )  # fmt: skip
    text = format_line(det)
    back = parse_line(text, "l")
    assert (back.gravity, back.notes) == (det.gravity, det.notes)
    old = json.loads(text)
    del old["gravity"], old["notes"]
    back = parse_line(json.dumps(old), "l")
    assert (back.gravity, back.notes) == (None, ())
    assert "gravity" not in json.loads(format_line(back))
    old["notes"] = "not a list"
    with pytest.raises(ValueError, match=r"^FILE:3: 'notes' must be a list of strings$"):
        parse_line(json.dumps(old), "FILE:3")
