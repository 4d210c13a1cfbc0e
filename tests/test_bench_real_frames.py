"""bench/real_frames.py: the count against hand-drawn 2D boxes (class, IoU, duplicates, threshold),
the boxes file's validation (one line naming the file and what is wrong), the committed boxes
file, and a run of the bundled model on a tiny frame folder (sheet and JSON written)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.structures.classes import CLASSES, class_index
from bench import real_frames
from bench.contact_sheet import GAP, TITLE_HEIGHT
from bench.real_frames import Count, HandBoxes, count, match, read_boxes
from tests.helpers.runtime_frames import H, W, write_scene_folder
from tests.helpers.samples import SAMPLE_MODEL

CHAIR, TABLE = class_index("chair"), class_index("table")


def _truth(*objects: tuple[int, list[float]]) -> HandBoxes:
    return HandBoxes(np.array([c for c, _ in objects], np.int64), np.array([b for _, b in objects], float))


def _count(truth: HandBoxes, *dets: tuple[int, float, list[float]], threshold: float = 0.5) -> Count:
    ids = np.array([d[0] for d in dets], np.int64)
    scores = np.array([d[1] for d in dets], float)
    boxes = np.array([d[2] for d in dets], float).reshape(-1, 4)
    return count(truth, ids, scores, boxes, threshold)


# ----------------------------------------------------------------------------- counting


def test_a_detection_of_the_right_class_on_the_object_is_right() -> None:
    c = _count(_truth((CHAIR, [0, 0, 100, 100])), (CHAIR, 0.9, [5, 5, 100, 100]))
    assert c == Count(objects=1, found=1, detections=1, right=1)
    assert (c.recall, c.precision) == (1.0, 1.0)


def test_another_class_on_the_object_is_wrong_and_the_object_missed() -> None:
    c = _count(_truth((CHAIR, [0, 0, 100, 100])), (TABLE, 0.9, [0, 0, 100, 100]))
    assert c == Count(objects=1, found=0, detections=1, right=0)


def test_iou_just_below_half_is_wrong_and_exactly_half_is_right() -> None:
    truth = _truth((CHAIR, [0, 0, 100, 100]))
    assert _count(truth, (CHAIR, 0.9, [0, 0, 100, 49.9])).right == 0  # IoU 0.499
    assert _count(truth, (CHAIR, 0.9, [0, 0, 100, 50])).right == 1  # IoU 0.5


def test_a_duplicate_counts_once_and_the_higher_score_takes_the_object() -> None:
    truth = _truth((CHAIR, [0, 0, 100, 100]))
    ids, scores = np.array([CHAIR, CHAIR]), np.array([0.6, 0.9])
    boxes = np.array([[0, 0, 100, 100], [0, 0, 90, 100]], float)  # the lower score fits better
    assert match(truth, ids, scores, boxes, 0.5).tolist() == [-1, 0]
    assert count(truth, ids, scores, boxes, 0.5) == Count(objects=1, found=1, detections=2, right=1)


def test_two_objects_of_a_class_each_take_the_detection_that_overlaps_them() -> None:
    truth = _truth((CHAIR, [0, 0, 100, 100]), (CHAIR, [200, 0, 300, 100]))
    ids, scores = np.array([CHAIR, CHAIR]), np.array([0.9, 0.8])
    boxes = np.array([[200, 0, 290, 100], [10, 0, 100, 100]], float)
    assert match(truth, ids, scores, boxes, 0.5).tolist() == [1, 0]


def test_detections_below_the_threshold_are_neither_counted_nor_matched() -> None:
    truth = _truth((CHAIR, [0, 0, 100, 100]))
    below = _count(truth, (CHAIR, 0.49, [0, 0, 100, 100]))
    assert below == Count(objects=1, found=0, detections=0, right=0)
    assert (below.recall, below.precision) == (0.0, None)
    assert _count(truth, (CHAIR, 0.49, [0, 0, 100, 100]), threshold=0.4).right == 1


def test_a_frame_with_nothing_to_find_and_the_sum() -> None:
    empty = _count(_truth(), (CHAIR, 0.8, [0, 0, 10, 10]))
    assert empty == Count(objects=0, found=0, detections=1, right=0) and empty.recall is None
    assert empty + Count(2, 1, 3, 1) == Count(2, 1, 4, 1)


# ----------------------------------------------------------------------------- the boxes file


def _write(tmp_path: Path, doc: object) -> Path:
    path = tmp_path / "boxes.json"
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def _doc(obj: object, **frame: object) -> dict:
    return {"image_size": [640, 480], "frames": {"f": {"objects": [obj], **frame}}}


@pytest.mark.parametrize(
    ("doc", "problem"),
    [
        ("{not json", "malformed JSON"),
        ({"frame": {}}, "unknown key 'frame'"),
        ({"frames": {}}, "'frames' must be an object"),
        ({"image_size": [640], "frames": {"f": {"objects": []}}}, "image_size must be [width, height]"),
        ({"frames": {"f": {"objects": {}}}}, "frames.f.objects must be a list"),
        (
            _doc({"class": "cupboard", "box": [0, 0, 1, 1]}),
            "frames.f.objects[0]: unknown class name 'cupboard'",
        ),
        (_doc({"class": "chair", "box": [0, 0, 1]}), "'box' must be [x1, y1, x2, y2]"),
        (_doc({"class": "chair", "box": [0, 0, 1, None]}), "'box' must be [x1, y1, x2, y2]"),
        (_doc({"class": "chair", "box": [10, 0, 5, 8]}), "empty or reversed"),
        (_doc({"class": "chair", "box": [0, 10, 5, 10]}), "empty or reversed"),
        (_doc({"class": "chair", "box": [600, 0, 641, 10]}), "outside the 640x480 image"),
        (_doc({"class": "chair", "box": [-1, 0, 10, 10]}), "outside the 640x480 image"),
        (_doc({"class": "chair", "bbox": [0, 0, 10, 10]}), "unknown key 'bbox'"),
        (_doc({"class": "chair", "box": [0, 0, 10, 10]}, notes=3), "frames.f.notes must be a string"),
    ],
)
def test_a_bad_boxes_file_is_one_line_naming_the_file_and_the_problem(
    tmp_path: Path, doc: object, problem: str
) -> None:
    path = _write(tmp_path, doc)
    with pytest.raises(InputError) as e:
        read_boxes(path)
    message = str(e.value)
    assert message.startswith(f"{path}: ") and problem in message and "\n" not in message


def test_a_missing_boxes_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"nowhere\.json: cannot read"):
        read_boxes(tmp_path / "nowhere.json")


def test_the_committed_boxes_file_validates() -> None:
    boxes = read_boxes(real_frames.DEFAULT_BOXES)  # classes and box limits are checked on read
    assert boxes.image_size == (640, 480) and len(boxes.frames) == 9
    for name, frame in boxes.frames.items():
        assert len(frame.class_ids) > 0 and frame.notes, name
        assert {CLASSES[i] for i in frame.class_ids} <= set(CLASSES)
        assert (frame.boxes[:, 2:] - frame.boxes[:, :2] >= 5).all(), name  # no degenerate slivers
        assert len(np.unique(frame.boxes, axis=0)) == len(frame.boxes), f"{name}: the same box twice"


# ----------------------------------------------------------------------------- the command


def _tiny_run(tmp_path: Path, boxes: dict, *extra: str) -> tuple[int, Path]:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    path = _write(tmp_path, boxes)
    out = tmp_path / "out"
    argv = [str(folder), "--model", str(SAMPLE_MODEL), "--boxes", str(path), "--out", str(out), *extra]
    return real_frames.main(argv), out


def _tiny_boxes(**frames: list) -> dict:
    return {"image_size": [W, H], "frames": {name: {"objects": objects} for name, objects in frames.items()}}


def test_the_bundled_model_on_a_tiny_folder_writes_the_sheet_and_the_counts(tmp_path: Path, capsys) -> None:
    chair = {"class": "chair", "box": [10, 10, 40, 60]}
    rc, out = _tiny_run(tmp_path, _tiny_boxes(a=[chair, {"class": "table", "box": [50, 40, 90, 70]}], b=[]))
    assert rc == 0, capsys.readouterr().err
    sheet = cv2.imread(str(out / "contact_sheet.png"))
    cell_h = TITLE_HEIGHT + H  # two tiles in one row under the header line
    assert sheet.shape == (TITLE_HEIGHT + cell_h + 2 * GAP, 2 * W + 3 * GAP, 3)
    report = json.loads((out / "real_frames.json").read_text())
    assert set(report["frames"]) == {"a", "b"} and report["total"]["objects"] == 2
    frames = report["frames"].values()
    assert report["total"]["detections"] == sum(f["detections"] for f in frames)
    assert len(report["frames"]["a"]["missed"]) == 2 - report["frames"]["a"]["found"]
    table = capsys.readouterr().out
    assert "| frame | objects | found | detections | right | recall | precision |" in table
    assert "| b | 0 | 0 |" in table and "| **total** | 2 |" in table


@pytest.mark.parametrize(
    ("frames", "problem"),
    [
        ({"a": [], "b": [], "c": []}, "frame 'c' is not a frame of"),
        ({"a": []}, "no entry for frame 'b' of"),
    ],
)
def test_boxes_that_do_not_name_the_folder_s_frames_stop_the_run(
    tmp_path: Path, capsys, frames: dict, problem: str
) -> None:
    rc, out = _tiny_run(tmp_path, _tiny_boxes(**frames))
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.startswith(f"real_frames: {tmp_path / 'boxes.json'}: ") and problem in err
    assert "\n" not in err and not out.exists()


def test_a_missing_folder_and_boxes_for_another_image_size_stop_the_run(tmp_path: Path, capsys) -> None:
    rc = real_frames.main(
        [str(tmp_path / "none"), "--model", str(SAMPLE_MODEL), "--out", str(tmp_path / "o")]
    )
    assert (
        rc == 1
        and capsys.readouterr().err.strip() == f"real_frames: {tmp_path / 'none'}: no such frame folder"
    )
    rc, _ = _tiny_run(
        tmp_path, {"image_size": [640, 480], "frames": {"a": {"objects": []}, "b": {"objects": []}}}
    )
    err = capsys.readouterr().err.strip()
    assert rc == 1 and f"the image is {W}x{H}" in err and "are for 640x480" in err
