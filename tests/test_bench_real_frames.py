"""bench/real_frames.py: the count against hand-drawn 2D boxes (class, IoU, duplicates, threshold),
the boxes files' validation (one line naming the file and what is wrong), the committed boxes
files, the 3D score on hand-made detections (bench/real_frames_3d.py), and a run of the bundled
model on a tiny frame folder (sheet and JSON written)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.metric import FrameTruth, retilt_boxes
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import CLASSES, class_index
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from bench import real_frames
from bench.contact_sheet import GAP, TITLE_HEIGHT
from bench.real_frames import Count, HandBoxes, count, match, read_boxes, read_boxes3d
from bench.real_frames_3d import Score3D, score_3d
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


def _write(tmp_path: Path, doc: object, name: str = "boxes.json") -> Path:
    path = tmp_path / name
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


# ----------------------------------------------------------------------------- the 3D boxes file

_CUBE = [0.0, 0.0, 3.0, 1.0, 1.0, 1.0, 0.0]  # a 1 m cube 3 m ahead


def _boxes2d_file(tmp_path: Path) -> real_frames.BoxesFile:
    objects = [{"class": "chair", "box": [0, 0, 10, 10]}, {"class": "table", "box": [20, 0, 40, 10]}]
    return read_boxes(_write(tmp_path, {"frames": {"f": {"objects": objects}}}))


_SKIPPED = {"object": 1, "class": "table", "why": "no depth"}


def _boxed(**changes: object) -> dict:
    return {"object": 0, "class": "chair", "box3d": _CUBE, **changes}


def _doc3d(frame: dict | None = None, **changes: object) -> dict:
    entry = {
        "R_tilt": np.eye(3).tolist(),
        "objects": [_boxed()],
        "skipped": [_SKIPPED],
    }
    entry.update(changes)
    return {"frames": {"f": entry}} if frame is None else frame


def _read3d(tmp_path: Path, doc: object) -> dict:
    return read_boxes3d(_write(tmp_path, doc, "boxes3d.json"), _boxes2d_file(tmp_path))


def test_a_good_3d_boxes_file_reads_as_truth_with_the_objects_indices(tmp_path: Path) -> None:
    frame = _read3d(tmp_path, _doc3d())["f"]
    assert frame.objects.tolist() == [0] and frame.truth.class_ids.tolist() == [CHAIR]
    np.testing.assert_array_equal(frame.truth.boxes3d, [_CUBE])


@pytest.mark.parametrize(
    ("doc", "problem"),
    [
        ("[1, 2", "malformed JSON"),
        (_doc3d(frame={"frames": {"g": {}}}), "'frames' must name the frames of"),
        (_doc3d(R_tilt=[[1, 0, 0], [0, 1, 0]]), "frames.f.R_tilt: expected a 3x3 rotation"),
        (_doc3d(R_tilt=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "frames.f.R_tilt: not a proper rotation"),
        (_doc3d(R_tilt="up"), "frames.f.R_tilt must be a 3x3 rotation"),
        (_doc3d(objects=[_boxed(box3d=_CUBE[:6])]), "'box3d' must be [x, y, z, l, w, h, theta] (7 numbers)"),
        (_doc3d(objects=[_boxed(box3d=[0, 0, 3, 0.5, 1, 1, 0])]), "needs l >= w > 0"),
        (_doc3d(objects=[_boxed(box3d=[0, 0, 3, 1, 1, -1, 0])]), "h > 0"),
        (_doc3d(objects=[_boxed(box3d=[0, 0, 3, 1, 1, 1, 2])]), "|theta| <= pi/2"),
        (_doc3d(objects=[_boxed(**{"class": "table"})]), "'class' must be 'chair' (hand-drawn object 0)"),
        (_doc3d(objects=[_boxed(object=2)]), "'object' must index the frame's 2 hand-drawn objects"),
        (_doc3d(objects=[_boxed(object=True)]), "'object' must index"),
        (_doc3d(objects=[{**_boxed(), "box": _CUBE}]), "unknown key 'box'"),
        (_doc3d(skipped=[{"object": 1, "class": "table"}]), "'why' must say why"),
        (_doc3d(skipped=[]), "hand-drawn object 1 is neither boxed nor skipped"),
        (_doc3d(skipped=[{**_boxed(why="x"), "box3d": None}]), "unknown key 'box3d'"),
        (_doc3d(skipped=[{"object": 0, "class": "chair", "why": "x"}, _SKIPPED]), "object 0 is listed twice"),
    ],
)  # fmt: skip
def test_a_bad_3d_boxes_file_is_one_line_naming_the_file_and_the_problem(
    tmp_path: Path, doc: object, problem: str
) -> None:
    with pytest.raises(InputError) as e:
        _read3d(tmp_path, doc)
    message = str(e.value)
    assert message.startswith(f"{tmp_path / 'boxes3d.json'}: ") and problem in message and "\n" not in message


def test_the_committed_3d_boxes_file_validates_against_the_boxes_file() -> None:
    boxes = read_boxes(real_frames.DEFAULT_BOXES)
    frames = read_boxes3d(real_frames.DEFAULT_BOXES3D, boxes)  # every object boxed or skipped, classes agree
    boxed = np.concatenate([f.truth.boxes3d for f in frames.values()])
    assert len(boxed) == 40 and sum(len(f.class_ids) for f in boxes.frames.values()) == 52
    assert ((boxed[:, 3:6] > 0.05) & (boxed[:, 3:6] < 3.0)).all()  # no sliver, no room-sized box
    assert ((boxed[:, 2] > 0.5) & (boxed[:, 2] < 8.0)).all()  # in front of the camera, within Kinect range
    doc = json.loads(real_frames.DEFAULT_BOXES3D.read_text())
    assert "never trained on" in doc["about"].lower()


# ----------------------------------------------------------------------------- the 3D score


def _truth3d(*objects: tuple[int, list[float]], R_tilt: np.ndarray | None = None) -> FrameTruth:
    ids = np.array([c for c, _ in objects], np.int64)
    return FrameTruth(
        ids, np.array([b for _, b in objects], float).reshape(-1, 7), np.eye(3) if R_tilt is None else R_tilt
    )


def _dets3d(*dets: tuple[int, float, list[float]], R_tilt: np.ndarray | None = None) -> FrameDetections:
    n = len(dets)
    return FrameDetections(
        frame="f",
        R_tilt=np.eye(3) if R_tilt is None else R_tilt,
        class_ids=np.array([d[0] for d in dets], np.int64),
        scores=np.array([d[1] for d in dets], float),
        boxes2d=np.tile([0.0, 0.0, 10.0, 10.0], (n, 1)) + 20 * np.arange(n)[:, None],  # apart: no 2D NMS
        boxes3d=np.array([d[2] for d in dets], float).reshape(-1, 7),
    )


def _score(truth: FrameTruth, det: FrameDetections, found: list[bool] | None = None) -> Score3D:
    found = [True] * len(truth.class_ids) if found is None else found
    return score_3d({"f": truth}, {"f": det}, {"f": np.array(found)}, threshold=0.5)


def _shifted(dx: float) -> list[float]:
    return [_CUBE[0] + dx, *_CUBE[1:]]


def test_a_perfect_detection_scores_ap_100_and_iou_1() -> None:
    s = _score(_truth3d((CHAIR, _CUBE)), _dets3d((CHAIR, 0.9, _CUBE)))
    assert [c.name for c in s.classes] == ["chair"] and 100 * s.map == pytest.approx(100.0)
    assert s.median_iou == pytest.approx(1.0) and s.found_ious.tolist() == pytest.approx([1.0])


def test_a_shifted_detection_has_the_overlap_s_iou_and_counts_at_0_25_only() -> None:
    near = _score(_truth3d((CHAIR, _CUBE)), _dets3d((CHAIR, 0.9, _shifted(0.5))))
    assert near.median_iou == pytest.approx(0.5 / 1.5) and near.map == pytest.approx(1.0)  # IoU 1/3 >= 0.25
    far = _score(_truth3d((CHAIR, _CUBE)), _dets3d((CHAIR, 0.9, _shifted(0.7))))
    assert far.median_iou == pytest.approx(0.3 / 1.7) and far.map == 0.0  # IoU 0.18 < 0.25


def test_a_detection_of_another_class_scores_nothing() -> None:
    s = _score(_truth3d((CHAIR, _CUBE)), _dets3d((TABLE, 0.9, _CUBE)))
    assert s.map == 0.0 and s.median_iou == 0.0
    assert [c.name for c in s.classes] == ["chair"]  # the table has no 3D box: not in the mean


def test_the_mean_is_over_the_classes_with_a_3d_box_and_the_median_over_the_objects_found() -> None:
    truth = _truth3d((CHAIR, _CUBE), (TABLE, [3.0, 0.0, 3.0, 1.0, 1.0, 1.0, 0.0]))
    det = _dets3d((CHAIR, 0.9, _CUBE), (TABLE, 0.8, [5.0, 0.0, 3.0, 1.0, 1.0, 1.0, 0.0]))
    s = _score(truth, det, found=[False, True])
    assert 100 * s.map == pytest.approx(50.0)  # chair 100, table 0
    assert s.best_iou["f"].tolist() == pytest.approx([1.0, 0.0]) and s.found_ious.tolist() == [0.0]
    assert _score(truth, det, found=[False, False]).median_iou is None


def test_below_the_threshold_a_detection_counts_for_ap_but_not_for_the_iou() -> None:
    s = _score(_truth3d((CHAIR, _CUBE)), _dets3d((CHAIR, 0.2, _CUBE)))
    assert s.map == pytest.approx(1.0) and s.median_iou == 0.0


def test_detections_in_another_tilt_frame_are_converted_through_their_corners() -> None:
    R_truth = rtilt_from_pitch_roll(np.radians(-15.0), np.radians(3.0))
    R_det = rtilt_from_pitch_roll(np.radians(-13.0), np.radians(2.0))
    box = [0.4, 0.2, 3.0, 1.2, 0.6, 0.8, 0.3]
    moved = retilt_boxes(np.array([box]), R_truth, R_det)[
        0
    ]  # the same camera-frame box, the other frame's yaw
    s = _score(_truth3d((CHAIR, box), R_tilt=R_truth), _dets3d((CHAIR, 0.9, moved), R_tilt=R_det))
    assert s.result.retilted_frames == ["f"] and s.median_iou > 0.9
    naive = _score(_truth3d((CHAIR, box), R_tilt=R_truth), _dets3d((CHAIR, 0.9, moved), R_tilt=R_truth))
    assert naive.median_iou < s.median_iou  # read in the wrong frame, the box is off


# ----------------------------------------------------------------------------- the command


def _tiny_run(tmp_path: Path, boxes: dict, *extra: str, boxes3d: dict | None = None) -> tuple[int, Path]:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    path = _write(tmp_path, boxes)
    out = tmp_path / "out"
    argv = [str(folder), "--model", str(SAMPLE_MODEL), "--boxes", str(path), "--out", str(out), *extra]
    argv += ["--boxes3d", str(_write(tmp_path, boxes3d, "boxes3d.json"))] if boxes3d else ["--no-3d"]
    return real_frames.main(argv), out


def _tiny_boxes(**frames: list) -> dict:
    return {"image_size": [W, H], "frames": {name: {"objects": objects} for name, objects in frames.items()}}


def test_the_bundled_model_on_a_tiny_folder_writes_the_sheet_and_the_counts(tmp_path: Path, capsys) -> None:
    chair = {"class": "chair", "box": [10, 10, 40, 60]}
    boxes3d = {"frames": {"a": _doc3d()["frames"]["f"], "b": {"R_tilt": np.eye(3).tolist()}}}
    boxes = _tiny_boxes(a=[chair, {"class": "table", "box": [50, 40, 90, 70]}], b=[])
    rc, out = _tiny_run(tmp_path, boxes, boxes3d=boxes3d)
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
    in3d = report["3d"]  # the frames' given R_tilt differs from the file's identity: converted
    assert set(in3d["classes"]) == {"chair"} and in3d["retilted_frames"] == ["a", "b"]
    assert [(o["object"], o["class"]) for o in in3d["frames"]["a"]] == [(0, "chair")]
    assert in3d["frames"]["b"] == [] and in3d["found"] == 0 and in3d["median_iou"] is None
    assert "| class | objects | detections | AP@0.25 |" in table and "| **mAP** | 1 |" in table


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


def test_a_detector_alone_is_counted_in_2d_and_needs_a_detector(tmp_path: Path, capsys) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    boxes = _write(tmp_path, _tiny_boxes(a=[{"class": "chair", "box": [10, 10, 40, 60]}], b=[]))
    out = tmp_path / "out"
    argv = [str(folder), "--boxes", str(boxes), "--out", str(out), "--detector", "yolox-nano"]
    assert real_frames.main([*argv, "--detector-alone"]) == 0
    report = json.loads((out / "real_frames.json").read_text())
    assert report["model_name"] == "yolox-nano alone" and "3d" not in report
    assert report["total"]["objects"] == 1 and not (out / "detections.jsonl").exists()
    with pytest.raises(SystemExit) as usage:
        real_frames.main([str(folder), "--boxes", str(boxes), "--out", str(out), "--detector-alone"])
    assert usage.value.code == 2
