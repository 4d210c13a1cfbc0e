"""a3d-eval end to end on a frame folder written here (README frame format), and the detections file.

The folder has three frames: f0 and f1 with ground truth, f2 without. Unit cubes at theta = 0 with
R_tilt = I: cubes whose centres differ by d along x have 3D IoU (1 - d) / (1 + d).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.cli.eval import main
from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import FrameDetections, parse_line, read_detections, write_detections
from a3d.runtime.structures.classes import class_index
from a3d.runtime.structures.geometry import box_corners_camera, rtilt_from_pitch_roll

H, W = 24, 32
EYE = np.eye(3).tolist()


def cube(x: float, z: float = 3.0) -> list[float]:
    return [x, 0.0, z, 1.0, 1.0, 1.0, 0.0]


def _gt_object(name: str, box3d: list[float], instance: int) -> dict:
    return {
        "class": name,
        "box3d": box3d,
        "box2d_visible": [2.5, 2.5, 10.5, 12.5],
        "box2d_amodal": [1.5, 1.5, 12.5, 14.5],
        "instance": instance,
    }


def write_folder(folder: Path, ground_truth: dict[str, list[dict] | None]) -> None:
    """Frames in the README format; ``None`` ground truth: a frame without NAME.gt.json."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "intrinsics.json").write_text(json.dumps({"fx": 30.0, "fy": 30.0, "cx": 15.5, "cy": 11.5}))
    for name, objects in ground_truth.items():
        cv2.imwrite(str(folder / f"{name}.color.png"), np.full((H, W, 3), 90, np.uint8))
        cv2.imwrite(str(folder / f"{name}.depth.png"), np.full((H, W), 3000, np.uint16))
        if objects is not None:
            (folder / f"{name}.meta.json").write_text(json.dumps({"R_tilt": EYE}))
            (folder / f"{name}.gt.json").write_text(json.dumps({"objects": objects}))


def det_line(frame: str, items: list[tuple[str, float, list[float]]]) -> FrameDetections:
    n = len(items)
    return FrameDetections(
        frame=frame,
        R_tilt=np.eye(3),
        class_ids=np.array([class_index(c) for c, _, _ in items], dtype=np.int64),
        scores=np.array([s for _, s, _ in items], float),
        boxes2d=np.array([[10.0 * i, 0.0, 10.0 * i + 5.0, 5.0] for i in range(n)]).reshape(n, 4),
        boxes3d=np.array([b for _, _, b in items], float).reshape(n, 7),
        color=f"{frame}.color.png",
        depth=f"{frame}.depth.png",
        timing={"network": 0.5},
    )


@pytest.fixture
def scene(tmp_path: Path) -> tuple[Path, Path]:
    folder = tmp_path / "frames"
    write_folder(
        folder,
        {
            "f0": [_gt_object("chair", cube(0), 1), _gt_object("table", cube(3), 2)],
            "f1": [_gt_object("chair", cube(0), 1), _gt_object("bed", cube(-3), 2)],
            "f2": None,
        },
    )
    detections = tmp_path / "detections.jsonl"
    write_detections(
        detections,
        [
            det_line("f0", [("chair", 0.9, cube(0)), ("chair", 0.4, cube(0.5)), ("table", 0.8, cube(3.5))]),
            det_line("f1", [("chair", 0.7, cube(10))]),
            det_line("f2", [("lamp", 0.9, cube(0))]),
        ],
    )
    return folder, detections


def test_cli_end_to_end_prints_the_table_and_writes_eval_json_and_the_png(scene, tmp_path, capsys) -> None:
    folder, detections = scene
    out = tmp_path / "out"
    assert main([str(folder), "--detections", str(detections), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    # chair: 2 GT; ranked f0 0.9 TP, f1 0.7 FP (x=10), f0 0.4 FP (duplicate of the matched chair)
    #   -> precision 1, 1/2, 1/3 at recall 1/2: t = 0 ... 0.5 -> 1, t = 0.6 ... 1 -> 0: AP = 6/11 = 54.5%
    #   at both thresholds.
    # table: 1 GT, one detection at IoU 1/3: AP 1 at 0.25, 0 at 0.5. bed: 1 GT, missed: AP 0.
    lines = {line.split("  ")[0]: line.split() for line in captured.out.splitlines()}
    assert lines["chair"] == ["chair", "2", "3", "54.5", "54.5"]
    assert lines["table"] == ["table", "1", "1", "100.0", "0.0"]
    assert lines["bed"] == ["bed", "1", "0", "0.0", "0.0"]
    assert lines["lamp"] == ["lamp", "0", "0", "-", "-"]  # its only line is for f2, which has no GT
    map_all = (6 / 11 + 1 + 0) / 19
    map_present = (6 / 11 + 1 + 0) / 3
    assert f"{100 * map_all:.1f}" in captured.out and f"{100 * map_present:.1f}" in captured.out
    assert "f2" in captured.err and "warning" in captured.err

    report = json.loads((out / "eval.json").read_text())
    assert report["classes"]["chair"]["ap"] == pytest.approx({"0.25": 6 / 11, "0.5": 6 / 11})
    assert report["classes"]["table"]["ap"] == {"0.25": 1.0, "0.5": 0.0}
    assert report["classes"]["lamp"] == {
        "num_gt": 0,
        "num_det": 0,
        "present": False,
        "ap": {"0.25": 0.0, "0.5": 0.0},
        "curve": {
            "0.25": {"recall": [], "precision": [], "score": []},
            "0.5": {"recall": [], "precision": [], "score": []},
        },
    }
    chair_curve = report["classes"]["chair"]["curve"]["0.25"]
    assert chair_curve == {"recall": [0.5, 0.5], "precision": [1.0, 0.333333], "score": [0.9, 0.4]}
    assert report["map"]["0.25"] == pytest.approx({"all_classes": map_all, "present_classes": map_present})
    assert report["map"]["0.5"] == pytest.approx({"all_classes": 6 / 11 / 19, "present_classes": 6 / 11 / 3})
    assert report["present_classes"] == ["bed", "chair", "table"]
    assert report["protocol"]["iou_thresholds"] == [0.25, 0.5] and report["protocol"]["nms_iou"] == 0.3
    assert report["protocol"]["name"] == "paper" and not report["protocol"]["nms_overridden"]
    assert captured.out.splitlines()[1].startswith("protocol paper: 11-point AP (recall k/10)")
    assert report["inputs"]["frames_with_gt"] == 2 and report["inputs"]["skipped_frames_without_gt"] == ["f2"]

    png = cv2.imread(str(out / "pr_curves.png"))
    assert png is not None and png.shape == (1000, 1500, 3)
    # Drawn, not blank: the curve colours are there (BGR blue of 0.25, orange of 0.5).
    assert np.all(png == (180, 119, 31), axis=2).sum() > 100
    assert np.all(png == (14, 127, 255), axis=2).sum() > 100
    assert sorted(p.name for p in out.iterdir()) == ["eval.json", "pr_curves.png"]  # no temp files left


def test_cli_scores_the_shards_of_a_run_as_one_file(scene, tmp_path, capsys) -> None:
    folder, detections = scene
    assert main([str(folder), "--detections", str(detections)]) == 0
    whole = capsys.readouterr().out
    lines = detections.read_text().splitlines(keepends=True)
    shards = [tmp_path / "shard0.jsonl", tmp_path / "shard1.jsonl"]
    shards[0].write_text("".join(lines[0::2]))
    shards[1].write_text("".join(lines[1::2]))
    assert main([str(folder), "--detections", *map(str, shards)]) == 0
    assert capsys.readouterr().out == whole
    shards[1].write_text(lines[0])  # frame f0 in both files
    assert main([str(folder), "--detections", *map(str, shards)]) == 2
    assert f"{shards[1]}: frame 'f0' is also in {shards[0]}" in capsys.readouterr().err


def test_cli_thresholds_and_no_nms(scene, tmp_path) -> None:
    folder, detections = scene
    out = tmp_path / "out"
    assert (
        main([str(folder), "--detections", str(detections), "--out", str(out), "--no-nms", "--iou", "0.3"])
        == 0
    )
    report = json.loads((out / "eval.json").read_text())
    assert report["protocol"] == {
        **report["protocol"],
        "iou_thresholds": [0.3],
        "nms_iou": None,
        "nms_overridden": True,
    }
    assert report["classes"]["table"]["ap"] == {"0.3": 1.0}  # IoU 1/3 >= 0.3


def test_cli_protocol_sunrgbd_and_all_side_by_side(scene, tmp_path, capsys) -> None:
    folder, detections = scene
    out = tmp_path / "out"
    assert (
        main([str(folder), "--detections", str(detections), "--protocol", "sunrgbd", "--out", str(out)]) == 0
    )
    text = capsys.readouterr().out
    assert "protocol sunrgbd: AP = area under the interpolated PR curve; no 2D NMS; match IoU > t" in text
    # chair under sunrgbd: ranked TP, FP, FP at recall 1/2 -> area = 1/2 * 1 = 50.0 (paper: 6/11 = 54.5)
    lines = {line.split("  ")[0]: line.split() for line in text.splitlines()}
    assert lines["chair"] == ["chair", "2", "3", "50.0", "50.0"]
    assert "lamp" not in lines and "counter" not in lines  # not SUN RGB-D classes
    report = json.loads((out / "eval.json").read_text())
    assert report["protocol"]["name"] == "sunrgbd" and report["protocol"]["match"] == "IoU > threshold"
    assert report["protocol"]["ap"] == "area" and report["protocol"]["nms_iou"] is None
    assert len(report["classes"]) == 10
    # present: bed 0, chair 1/2, table 1 (IoU 1/3 > 0.25) -> mAP (0 + 0.5 + 1) / 3 = 0.5 (float32)
    assert report["map"]["0.25"]["present_classes"] == 0.5

    both = tmp_path / "both"
    assert main([str(folder), "--detections", str(detections), "--protocol", "all", "--out", str(both)]) == 0
    text = capsys.readouterr().out
    compared = text[text.index("AP@0.25 (percent) under each protocol") :]
    rows = {line.split("  ")[0]: line.split() for line in compared.splitlines()}
    assert rows["class"] == ["class", "#GT", "paper", "authors", "sunrgbd"]
    assert rows["chair"] == ["chair", "2", "54.5", "54.5", "50.0"]
    assert rows["lamp"] == ["lamp", "0", "-", "-", "-"]
    assert rows["mAP, classes with GT"][-3:] == [f"{100 * (6 / 11 + 1) / 3:.1f}"] * 2 + ["50.0"]
    for name in ("paper", "authors", "sunrgbd"):
        assert json.loads((both / name / "eval.json").read_text())["protocol"]["name"] == name
        assert (both / name / "pr_curves.png").is_file()
    authors = json.loads((both / "authors" / "eval.json").read_text())["protocol"]
    assert authors["recall_points"][3] == "0.30000000000000004" and authors["nms_box_convention"].startswith(
        "x2 - x1 + 1"
    )


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("{not json", "malformed JSON at line 1 column 2"),
        (
            '{"frame": "f0", "R_tilt": [[1,0,0],[0,1,0],[0,0,1]], "detections": [{"class": "sofa bed", '
            '"score": 1, "box2d": [0,0,1,1], "box3d": [0,0,3,1,1,1,0]}]}',
            "unknown class 'sofa bed'",
        ),
        ('{"frame": "nowhere", "R_tilt": [[1,0,0],[0,1,0],[0,0,1]], "detections": []}', "not a frame of"),
    ],
)
def test_cli_bad_detections_exit_2_with_a_one_line_message_naming_the_file(
    scene, capsys, line, message
) -> None:
    folder, detections = scene
    text = detections.read_text().splitlines()
    detections.write_text("\n".join([text[0], line, *text[1:]]) + "\n")
    assert main([str(folder), "--detections", str(detections)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(detections) in err and message in err
    if message != "not a frame of":
        assert f"{detections}:2:" in err


def test_cli_missing_inputs_exit_2(scene, tmp_path, capsys) -> None:
    folder, detections = scene
    assert main([str(folder), "--detections", str(tmp_path / "none.jsonl")]) == 2
    assert "none.jsonl" in capsys.readouterr().err
    empty = tmp_path / "empty"
    write_folder(empty, {"x": None})
    assert main([str(empty), "--detections", str(detections)]) == 2
    assert str(empty) in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main([str(folder)])  # --detections is required
    assert exit_.value.code == 2


def test_installed_command_exits_2_on_a_bad_file(scene) -> None:
    folder, detections = scene
    detections.write_text(detections.read_text() + '{"frame": "f1"}\n')
    script = Path(sys.executable).with_name("a3d-eval")  # the console script pip installed
    command = [str(script)] if script.exists() else [sys.executable, "-m", "a3d.runtime.cli.eval"]
    result = subprocess.run(
        [*command, str(folder), "--detections", str(detections)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert f"{detections}:4:" in result.stderr and result.stdout == ""


def test_empty_detections_file_scores_zero(scene, capsys) -> None:
    folder, detections = scene
    detections.write_text("")
    assert main([str(folder), "--detections", str(detections)]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("mAP")]
    assert [row[-2:] for row in rows] == [["0.0", "0.0"], ["0.0", "0.0"]]


# --- the detections file -------------------------------------------------------------------------


def test_detections_round_trip_and_corners_follow_the_boxes(tmp_path) -> None:
    R = rtilt_from_pitch_roll(0.2, -0.05)
    rng = np.random.default_rng(3)
    boxes3d = np.column_stack(
        [
            rng.normal(size=(5, 3)) + np.array([0, 0, 4]),
            rng.uniform(0.2, 2, (5, 3)),
            rng.uniform(-1.5, 1.5, 5),
        ]
    )
    original = FrameDetections(
        frame="0001",
        R_tilt=R,
        class_ids=np.array([0, 4, 4, 18, 9]),
        scores=rng.uniform(size=5),
        boxes2d=np.sort(rng.uniform(0, 400, (5, 2, 2)), axis=1).reshape(5, 4),
        boxes3d=boxes3d,
        timing={"proposals": 0.25, "network": 1.5},
        boxes2d_amodal=np.array([[0.0, 1.0, 2.0, 3.0]] * 5) + rng.uniform(0, 100, (5, 1)),
    )
    path = tmp_path / "d.jsonl"
    write_detections(path, [original, det_line("0002", [])])
    (back, empty) = read_detections(path)
    for name in ("R_tilt", "class_ids", "scores"):  # exact
        np.testing.assert_array_equal(getattr(back, name), getattr(original, name))
    # Boxes to 1 micrometre and 1e-4 pixel.
    np.testing.assert_allclose(back.boxes3d, boxes3d, rtol=0, atol=0.5e-6)
    np.testing.assert_allclose(back.boxes2d, original.boxes2d, rtol=0, atol=0.5e-4)
    np.testing.assert_allclose(back.boxes2d_amodal, original.boxes2d_amodal, rtol=0, atol=0.5e-4)
    np.testing.assert_allclose(back.corners, box_corners_camera(boxes3d, R), rtol=0, atol=0.5e-6)
    assert back.timing == original.timing and back.classes[1] == "chair"
    assert empty.frame == "0002" and empty.boxes3d.shape == (0, 7) and empty.boxes2d.shape == (0, 4)
    assert empty.boxes2d_amodal is None  # optional: absent when not written


_GOOD = {"class": "chair", "score": 0.5, "box2d": [0, 0, 5, 5], "box3d": [0, 0, 3, 1, 1, 1, 0]}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"frame": ""}, "'frame' must be a non-empty string"),
        ({"R_tilt": [[1, 0], [0, 1]]}, "'R_tilt' must be a 3x3 matrix"),
        ({"R_tilt": [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}, "R_tilt: not a proper rotation"),
        ({"detections": [{**_GOOD, "class": ["chair"]}]}, "detection 0: unknown class ['chair']"),
        ({"detections": {}}, "'detections' must be a list"),
        ({"detections": [{**_GOOD, "box3d": [0, 0, 3, 1, 1, 1]}]}, "'box3d' must be 7, got shape (1, 6)"),
        (
            {"detections": [_GOOD, {**_GOOD, "box3d": [0, 0, 3, 1, -1, 1, 0]}]},
            "detection 1: box3d has a size",
        ),
        ({"detections": [{**_GOOD, "score": float("nan")}]}, "detection 0: 'score' is not finite"),
        ({"detections": [{**_GOOD, "box2d": [5, 0, 0, 5]}]}, "x2 < x1"),
        ({"detections": [{k: v for k, v in _GOOD.items() if k != "score"}]}, "detection 0 has no 'score'"),
        ({"timing": {"a": "slow"}}, "'timing'"),
        ({"detections": [{**_GOOD, "box2d_amodal": [0, 0, 1, 1]}, _GOOD]}, "'box2d_amodal' given for some"),
        ({"detections": [{**_GOOD, "box2d_amodal": [0, 5, 1, 1]}]}, "detection 0: box2d_amodal has x2 < x1"),
        (
            {"detections": [{**_GOOD, "corners": [[0, 0, 0]] * 7}]},
            "'corners' must be 8x3, got shape (1, 7, 3)",
        ),
    ],
)
def test_bad_lines_are_one_line_errors_naming_file_and_line(change, message) -> None:
    line = {"frame": "f", "R_tilt": EYE, "detections": [_GOOD], **change}
    with pytest.raises(InputError) as error:
        parse_line(json.dumps(line), "d.jsonl:7")
    assert str(error.value).startswith("d.jsonl:7: ") and message in str(error.value)


def test_a_frame_given_twice_is_an_error(tmp_path) -> None:
    path = tmp_path / "d.jsonl"
    write_detections(path, [det_line("a", []), det_line("b", []), det_line("a", [])])
    with pytest.raises(InputError, match=r"d\.jsonl:3: frame 'a' already given on line 1"):
        read_detections(path)


def test_a_binary_file_is_an_input_error_naming_it(tmp_path) -> None:
    path = tmp_path / "d.jsonl"
    path.write_bytes(b"\xff\xfe\x00garbage\n")
    with pytest.raises(InputError, match=r"d\.jsonl:1: not UTF-8 text"):
        read_detections(path)
