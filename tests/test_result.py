"""A detection result (FrameDetections) as a Python user meets it: sized, iterable, indexable,
convertible, drawn on its image with OpenCV and logged to rerun as a3d-run's view logs it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from a3d.runtime import extras
from a3d.runtime.errors import InputError
from a3d.runtime.extras import MissingExtra
from a3d.runtime.io.detections_io import Detection, FrameDetections
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, class_index
from a3d.runtime.structures.geometry import Intrinsics, box_corners_camera
from a3d.runtime.viewer.shapes import projected_box_edges

K = Intrinsics(100.0, 100.0, 79.5, 59.5)
H, W = 120, 160
CHAIR, TABLE = class_index("chair"), class_index("table")


def _result(intrinsics: Intrinsics | None = K) -> FrameDetections:
    return FrameDetections(
        frame="f",
        R_tilt=np.eye(3),
        class_ids=np.array([CHAIR, TABLE]),
        scores=np.array([0.9, 0.55]),
        boxes2d=np.array([[20.5, 30.5, 60.5, 90.5], [90.5, 20.5, 150.5, 70.5]]),
        boxes3d=np.array([[-0.5, 0.2, 2.5, 0.5, 0.5, 0.9, 0.0], [0.6, 0.0, 3.0, 1.2, 0.8, 0.7, 0.3]]),
        intrinsics=intrinsics,
    )


def test_a_result_is_a_sequence_of_detections() -> None:
    result = _result()
    assert len(result) == 2 and len(result[result.scores > 1]) == 0
    assert [d.class_name for d in result] == ["chair", "table"]
    last = result[-1]
    assert isinstance(last, Detection)
    assert (last.class_name, last.class_id, last.score) == ("table", TABLE, 0.55)
    np.testing.assert_array_equal(last.box3d, result.boxes3d[1])
    np.testing.assert_allclose(last.corners, box_corners_camera(result.boxes3d[1:], np.eye(3))[0])
    with pytest.raises(IndexError):
        result[2]
    assert result[result.scores >= 0.6].classes == ["chair"]  # a mask, as detect's threshold uses
    assert result[[1, 0]].classes == ["table", "chair"] and result[1:].classes == ["table"]
    assert result[1:].frame == "f" and result[1:].intrinsics == K


def test_to_list_is_the_lines_detections() -> None:
    rows = _result().to_list()
    assert [row["class"] for row in rows] == ["chair", "table"] and rows[1]["score"] == 0.55
    assert rows[0]["box3d"] == [-0.5, 0.2, 2.5, 0.5, 0.5, 0.9, 0.0]
    assert set(rows[0]) == {"class", "score", "box2d", "box3d", "corners"}  # no amodal box given
    assert np.asarray(rows[0]["corners"]).shape == (8, 3)


def test_draw_boxes_labels_and_projected_3d_boxes_in_the_class_colours() -> None:
    image = np.zeros((H, W, 3), np.uint8)
    result = _result()
    drawn = result.draw(image)
    assert not image.any(), "the image itself is left as it was"
    assert tuple(drawn[60, 21]) == CLASS_COLORS_RGB[CHAIR]  # the chair box's left edge (pixel 21)
    assert tuple(drawn[60, 150]) == CLASS_COLORS_RGB[TABLE]  # the table box's right edge
    assert tuple(result.draw(image, bgr=True)[60, 21]) == CLASS_COLORS_RGB[CHAIR][::-1]
    flat = result.draw(image, boxes3d=False)
    only_3d = np.argwhere((drawn != flat).any(axis=2))
    assert len(only_3d) > 50, "the 3D boxes' edges are drawn"
    segments = projected_box_edges(result.boxes3d, result.R_tilt, K, (H, W))
    segments = segments[np.isfinite(segments).all(axis=(1, 2))]
    points = np.concatenate([np.linspace(a, b, 200) for a, b in segments])  # (x, y) along every edge
    nearest = np.min(np.linalg.norm(only_3d[:, None, ::-1] - points[None], axis=2), axis=1)
    assert nearest.max() < 1.6, "every pixel the 3D boxes add lies on a projected edge"
    assert (_result(intrinsics=None).draw(image) == flat).all()  # no camera: no 3D boxes
    with pytest.raises(InputError, match=r"^image: expected an \(H, W, 3\) uint8 array, got float32"):
        result.draw(image.astype(np.float32))


def test_log_writes_the_views_boxes(tmp_path: Path) -> None:
    import rerun as rr

    from tests.rrd_reader import as_array, read_columns

    path = tmp_path / "result.rrd"
    rec = rr.RecordingStream("a3d-test")
    rec.save(str(path))
    rec.set_time("frame", sequence=3)
    result = _result()
    result.log("world/detections", recording=rec)
    rec.flush()
    rr.disconnect(rec)
    logged = read_columns(path, "/world/detections")[3]
    assert logged["Boxes3D:labels"] == ["chair 0.90", "table 0.55"]
    assert logged["Boxes3D:class_ids"] == [CHAIR + 1, TABLE + 1]  # softmax ids, the view's annotation ids
    np.testing.assert_allclose(as_array(logged["Boxes3D:centers"]), result.boxes3d[:, :3], atol=1e-6)


def test_log_without_rerun_is_one_line_naming_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(extras, "installed", lambda module: module != "rerun")
    with pytest.raises(MissingExtra) as caught:
        _result().log()
    assert str(caught.value) == (
        "FrameDetections.log needs the 'view' extra: pip install 'a3d[view]' (rerun is missing)"
    )
