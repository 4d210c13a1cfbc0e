"""The Python API (a3d.runtime.Detector) and the array-first pipeline against a3d-run."""

from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import pytest

from a3d.runtime import Detector
from a3d.runtime.cli import run as run_cli
from a3d.runtime.postprocess.box_limits import bound_boxes, near_range
from a3d.runtime.sources.arrays import ArrayError
from a3d.runtime.sources.folder import FolderSource, read_meta
from a3d.runtime.structures.classes import class_index
from tests.helpers.samples import PINNED_DETECTIONS as PINNED
from tests.helpers.samples import PINNED_MODEL, SAMPLES


@pytest.fixture(scope="module")
def run_lines(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    out = tmp_path_factory.mktemp("run") / "det.jsonl"
    argv = [str(SAMPLES), "--model", str(PINNED_MODEL), "--output", str(out), "--headless", "--threads", "2"]
    assert run_cli.main(argv) == 0
    return {d["frame"]: d for d in map(json.loads, out.read_text().splitlines())}


@pytest.fixture(scope="module")
def detector() -> Detector:
    return Detector.load(PINNED_MODEL, threads=2)


def test_sample_frames_carry_no_notes(run_lines: dict[str, dict]) -> None:
    """Notes say what degraded: a full proposal list (the configured top N) and centres clamped on
    the low-scoring tail are normal operation, and the clean sample frames have neither."""
    assert run_lines and all("notes" not in line for line in run_lines.values()), [
        line.get("notes") for line in run_lines.values()
    ]


def _without_files(line: dict) -> dict:
    return {k: v for k, v in line.items() if k not in ("timing", "color", "depth")}


def test_a3d_run_on_samples_is_pinned_to_the_output_before_the_redesign(run_lines: dict[str, dict]) -> None:
    """tests/data/samples_detections.jsonl was written by a3d-run before the runtime was regrouped
    and made array-first; boxes and scores must stay within 1e-6 of it, detection for detection,
    once its 3D boxes are bounded as a3d-run now bounds them (postprocess.box_limits)."""
    pinned = [json.loads(line) for line in PINNED.read_text().splitlines()]
    assert [p["frame"] for p in pinned] == sorted(run_lines)
    frames = {loader.name: loader for loader in FolderSource(SAMPLES)}
    for want in pinned:
        got = run_lines[want["frame"]]
        near = near_range(frames[want["frame"]].load().depth)
        classes = np.array([class_index(d["class"]) for d in want["detections"]])
        before = np.array([d["box3d"] for d in want["detections"]])
        bounded = bound_boxes(before, classes, near)
        scores = np.array([d["score"] for d in got["detections"]])
        assert bounded.notes(scores) == [note for note in got.get("notes", []) if "box" in note]
        moved = (bounded.boxes3d != before).any(axis=1)
        assert moved.mean() < 0.2, "the bounds change a few boxes, not the detector"
        for d, box in zip(want["detections"], bounded.boxes3d.tolist(), strict=True):
            d["box3d"] = box
        np.testing.assert_allclose(got["R_tilt"], want["R_tilt"], atol=1e-9)
        assert [d["class"] for d in got["detections"]] == [d["class"] for d in want["detections"]]
        for key in ("score", "box2d", "box2d_amodal", "box3d"):
            a = np.array([d[key] for d in got["detections"]], np.float64)
            b = np.array([d[key] for d in want["detections"]], np.float64)
            exact = ~moved if key == "box3d" else np.ones(len(a), bool)
            np.testing.assert_allclose(
                a[exact], b[exact], rtol=0, atol=1e-6, err_msg=f"{want['frame']} {key}"
            )
            # a clamped centre slides along its ray (up to ~10x): the pinned 1e-6 rounding grows with it
            np.testing.assert_allclose(
                a[~exact], b[~exact], rtol=1e-5, atol=1e-6, err_msg=f"{want['frame']} {key}"
            )


def test_detect_on_arrays_equals_a3d_run_line(detector: Detector, run_lines: dict[str, dict]) -> None:
    source = FolderSource(SAMPLES)
    assert len(source.refs) == len(run_lines) == 6
    for ref in source.refs:
        rgb = cv2.imread(str(ref.color_path), cv2.IMREAD_COLOR)[..., ::-1]
        depth_mm = cv2.imread(str(ref.depth_path), cv2.IMREAD_UNCHANGED)
        assert depth_mm.dtype == np.uint16
        K = source.intrinsics.matrix()  # a 3x3 matrix here; (fx, fy, cx, cy) in the next check
        result = detector.detect(rgb, depth_mm, K, read_meta(ref).R_tilt, name=ref.name, score_threshold=0)
        assert _without_files(json.loads(result.to_json())) == _without_files(run_lines[ref.name])
    # float metres and a 4-tuple give the same line as uint16 millimetres and K
    ref = source.refs[0]
    rgb = cv2.imread(str(ref.color_path), cv2.IMREAD_COLOR)[..., ::-1]
    metres = cv2.imread(str(ref.depth_path), cv2.IMREAD_UNCHANGED).astype(np.float32) / np.float32(1000)
    K = source.intrinsics
    again = detector.detect(rgb, metres, (K.fx, K.fy, K.cx, K.cy), read_meta(ref).R_tilt, name=ref.name,
                            score_threshold=0)  # fmt: skip
    assert _without_files(json.loads(again.to_json())) == _without_files(run_lines[ref.name])
    # The default returns what the viewer shows: the detections scoring >= 0.5, a3d-run's line cut there.
    shown = detector.detect(rgb, metres, K, read_meta(ref).R_tilt, name=ref.name)
    line = run_lines[ref.name]["detections"]
    assert 0 < len(shown) < len(line)
    cut = [d for d in json.loads(again.to_json())["detections"] if d["score"] >= 0.5]
    assert json.loads(shown.to_json())["detections"] == cut


RGB = np.zeros((24, 32, 3), np.uint8)
DEPTH = np.full((24, 32), 2.0, np.float32)
K4 = (30.0, 30.0, 15.5, 11.5)


@pytest.mark.parametrize(
    ("arrays", "argument", "says"),
    [
        ({"color": RGB[..., 0]}, "color", "(H, W, 3) uint8 RGB"),
        ({"color": RGB.astype(np.float32)}, "color", "float32"),
        ({"color": [[1, 2, 3]]}, "color", "numpy array"),
        ({"depth": DEPTH[None]}, "depth", "(H, W) array"),
        ({"depth": DEPTH.astype(np.int32)}, "depth", "int32"),
        ({"depth": DEPTH[:12]}, "depth", "12x32 but color is 24x32"),
        ({"depth": np.where(DEPTH > 0, np.nan, 0).astype(np.float32)}, "depth", "NaN"),
        ({"depth": -DEPTH}, "depth", "negative"),
        ({"intrinsics": (0.0, 30.0, 15.5, 11.5)}, "intrinsics", "positive"),
        ({"intrinsics": (30.0, 30.0, 15.5)}, "intrinsics", "(fx, fy, cx, cy) or a 3x3"),
        ({"intrinsics": np.eye(3) * 2}, "intrinsics", "[[fx, 0, cx]"),
        ({"R_tilt": np.ones((3, 3))}, "R_tilt", "not a proper rotation"),
    ],
)
def test_bad_arrays_give_one_line_naming_the_argument(
    detector: Detector, arrays: dict, argument: str, says: str
) -> None:
    given = {"color": RGB, "depth": DEPTH, "intrinsics": K4, "R_tilt": None} | arrays
    with pytest.raises(ArrayError) as caught:
        detector.detect(given["color"], given["depth"], given["intrinsics"], given["R_tilt"])
    message = str(caught.value)
    assert isinstance(caught.value, ValueError) and "\n" not in message
    assert message.startswith(f"{argument}: ") and says in message, message


def test_uint16_depth_takes_its_scale(detector: Detector) -> None:
    """TUM's 5000 units per metre: depth_scale 0.0002 gives the same detections as metres."""
    units = np.full((24, 32), 10000, np.uint16)
    a = detector.detect(RGB, units, K4, depth_scale=0.0002)
    b = detector.detect(RGB, np.full((24, 32), 2.0, np.float32), K4)
    assert _without_files(json.loads(a.to_json())) == _without_files(json.loads(b.to_json()))
    with pytest.raises(ArrayError, match=r"^depth_scale: "):
        detector.detect(RGB, units, K4, depth_scale=-1.0)


def test_implausible_depth_warns_once_naming_depth_scale(detector: Detector) -> None:
    """TUM's 5000 units per metre read as millimetres make a 3.5 m room 17.5 m deep: one warning
    per detector naming depth_scale and the median; a plausible frame says nothing."""
    tum = np.full((24, 32), 17500, np.uint16)
    with pytest.warns(UserWarning, match=r"^depth: the median valid depth is 17\.5 m, .*check depth_scale"):
        detector.detect(RGB, tum, K4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second warning would fail here
        detector.detect(RGB, tum, K4)
        Detector.load(PINNED_MODEL, threads=1).detect(RGB, tum, K4, depth_scale=0.0002)  # 3.5 m: fine
    with pytest.warns(UserWarning, match=r"median valid depth is 0\.05 m, .*float depth must be in metres"):
        Detector.load(PINNED_MODEL, threads=1).detect(RGB, np.full((24, 32), 0.05, np.float32), K4)


def test_score_threshold_is_checked(detector: Detector) -> None:
    with pytest.raises(ValueError, match=r"^score_threshold: must be in \[0, 1\], got 1.5"):
        detector.detect(RGB, DEPTH, K4, score_threshold=1.5)
