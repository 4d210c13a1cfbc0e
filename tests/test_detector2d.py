"""a3d.runtime.detector2d: the three output layouts decoded into original-image pixels, class names,
the class map, the errors a user sees, and the bundled YOLOX-Nano.

The graphs are tests/helpers/detector_files.py's: the decoded boxes are known. The image is 300 x
150 into a 96 x 64 input, so the letterbox scale is 0.32 and the lower part of the input is padding.
"""

from __future__ import annotations

import hashlib
import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.detector2d import DETECTORS, Detector2D
from a3d.runtime.detector2d.layouts import NANODET, YOLOX, Layout
from a3d.runtime.detector2d.names import COCO80
from a3d.runtime.detector2d.preprocess import network_input
from a3d.runtime.errors import InputError
from a3d.runtime.structures.classes import CLASSES
from tests.helpers.detector_files import INPUT_HW, boxes_outputs, detector_graph, nanodet_outputs, yolox_grid

IMAGE = np.zeros((150, 300, 3), np.uint8)  # letterboxed by r = min(64 / 150, 96 / 300) = 0.32
R = 0.32
MODELS = Path(__file__).resolve().parents[1] / "runtime" / "models"


@pytest.fixture
def yolox_file(tmp_path: Path) -> Path:
    names = {"names": json.dumps(["cat", "chair", "tv"])}
    return detector_graph(tmp_path / "tiny_yolox.onnx", [1, 3, *INPUT_HW], {"output": yolox_grid()}, names)


def test_yolox_layout_decodes_into_the_original_image(yolox_file: Path) -> None:
    detector = Detector2D.load(yolox_file)
    assert (detector.name, detector.layout) == ("tiny_yolox", "yolox")
    assert detector.class_names == ("cat", "chair", "tv")
    found = detector.detect(IMAGE)
    assert found.names == ("chair", "tv")
    np.testing.assert_allclose(found.scores, [0.72, 0.3], rtol=1e-6)
    chair = np.array([36, 12, 52, 24]) / R
    tv = np.minimum(np.array([48, 24, 80, 72]) / R, [300, 150, 300, 150])  # clipped to the image
    np.testing.assert_allclose(found.boxes, [chair, tv], rtol=1e-5)
    assert found.class_ids.tolist() == [CLASSES.index("chair"), CLASSES.index("monitor")]
    assert found.candidates.shape == (2, len(CLASSES)) and found.candidates.dtype == bool
    assert [np.flatnonzero(c).tolist() for c in found.candidates] == [
        [CLASSES.index("chair")],
        [CLASSES.index("monitor"), CLASSES.index("television")],
    ]
    assert found.boxes.dtype == found.scores.dtype == np.float64 and found.class_ids.dtype == np.int64


def test_nanodet_layout_decodes_the_distance_distributions(tmp_path: Path) -> None:
    outputs = nanodet_outputs()
    path = detector_graph(tmp_path / "tiny_nanodet.onnx", [1, 3, *INPUT_HW], outputs)
    names = tmp_path / "names.txt"
    names.write_text("chair\ncup\ncouch\n")
    detector = Detector2D.load(path, names=names)
    assert detector.layout == "nanodet"
    found = detector.detect(IMAGE)
    assert found.names == ("couch",) and found.class_ids.tolist() == [CLASSES.index("sofa")]
    np.testing.assert_allclose(found.scores, [0.7], rtol=1e-6)
    np.testing.assert_allclose(found.boxes, [np.array([40, 8, 88, 32]) / R], rtol=1e-5)


@pytest.mark.parametrize("batched", [True, False])
def test_boxes_layout_takes_rgb_in_0_to_1_and_scales_boxes_back(tmp_path: Path, batched: bool) -> None:
    lead = [1] if batched else []
    outputs = boxes_outputs(batched)  # scores: R, G, B of the input, 1.0, 0.6, 0.0 for the image below
    metadata = {"names": "{0: 'bed', 1: 'toilet', 2: 'sink'}"}  # as ultralytics writes it
    path = detector_graph(tmp_path / "tiny_boxes.onnx", [*lead, 3, 40, 60], outputs, metadata)
    detector = Detector2D.load(path)
    assert detector.layout == "boxes" and detector.class_names == ("bed", "toilet", "sink")
    image = np.empty((150, 300, 3), np.uint8)
    image[:] = (255, 153, 0)
    found = detector.detect(image)
    assert found.names == ("bed", "toilet")  # the sink scores 0, under the threshold
    np.testing.assert_allclose(found.scores, [1.0, 0.6], rtol=1e-5)
    np.testing.assert_allclose(found.boxes, [[30, 15, 150, 75], [150, 75, 300, 150]], rtol=1e-5)


def test_a_class_map_file_replaces_the_built_in_one_with_candidates(yolox_file: Path, tmp_path: Path) -> None:
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({"cat": ["sofa", "chair"], "person": "chair"}))  # "person": not its class
    found = Detector2D.load(yolox_file, class_map=mapping).detect(IMAGE)
    assert found.names == ("cat",) and found.class_ids.tolist() == [CLASSES.index("sofa")]
    assert np.flatnonzero(found.candidates[0]).tolist() == sorted(CLASSES.index(c) for c in ("sofa", "chair"))
    np.testing.assert_allclose(found.boxes, [np.array([32, 16, 48, 32]) / R], rtol=1e-5)


def test_network_input_letterboxes_bgr_at_the_top_left() -> None:
    image = np.empty((4, 8, 3), np.uint8)
    image[:] = (10, 20, 30)  # RGB
    yolox = Layout(YOLOX, "image", (8, 8), True, ("output",), 3, (8,))
    tensor, scale = network_input(image, yolox)
    assert tensor.shape == (1, 3, 8, 8) and tensor.dtype == np.float32 and scale.tolist() == [1, 1, 1, 1]
    assert tensor[0, :, 3, 7].tolist() == [30, 20, 10] and tensor[0, :, 4, 0].tolist() == [114, 114, 114]
    nanodet = Layout(NANODET, "image", (8, 8), True, ("c", "r"), 3, (8,))
    tensor, _ = network_input(image, nanodet)
    mean, std = np.array([103.53, 116.28, 123.675]), np.array([57.375, 57.12, 58.395])
    np.testing.assert_allclose(tensor[0, :, 0, 0], (np.array([30, 20, 10]) - mean) / std, rtol=1e-5)
    np.testing.assert_allclose(tensor[0, :, 7, 0], -mean / std, rtol=1e-5)


def test_an_unknown_layout_is_one_line_naming_the_file(tmp_path: Path) -> None:
    outputs = {"logits": np.zeros((1, 10), np.float32)}
    path = detector_graph(tmp_path / "classifier.onnx", [1, 3, 32, 32], outputs)
    with pytest.raises(InputError, match="unknown 2D detector layout: outputs logits \\(1, 10\\)") as error:
        Detector2D.load(path)
    assert str(path) in str(error.value) and "\n" not in str(error.value)


def test_a_names_file_of_another_count_is_an_error(yolox_file: Path, tmp_path: Path) -> None:
    names = tmp_path / "coco80.names"
    names.write_text("\n".join(COCO80) + "\n")
    with pytest.raises(InputError, match=r"has 80 class names but the detector .* has 3 classes") as error:
        Detector2D.load(yolox_file, names=names)
    assert str(error.value).startswith(f"{names}: ")


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        ({"chair": []}, "names no a3d class"),
        ({}, "names no a3d class"),
        ({"chair": "throne"}, "maps to 'throne', not an a3d class"),
        ({"armchair": "chair"}, "names no class of the detector"),
    ],
)
def test_a_bad_class_map_is_an_error_naming_the_file(yolox_file: Path, tmp_path: Path, mapping: dict,
                                                      message: str) -> None:  # fmt: skip
    path = tmp_path / "map.json"
    path.write_text(json.dumps(mapping))
    with pytest.raises(InputError, match=message) as error:
        Detector2D.load(yolox_file, class_map=path)
    assert str(error.value).startswith(f"{path}: ")


def test_bad_arguments_are_one_line_errors(yolox_file: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such 2D detector file"):
        Detector2D.load(tmp_path / "missing.onnx")
    detector = Detector2D.load(yolox_file)
    with pytest.raises(InputError, match="color_rgb: expected an \\(H, W, 3\\) uint8"):
        detector.detect(np.zeros((150, 300), np.uint8))


def test_the_bundled_yolox_nano_loads_by_name_and_finds_little_in_a_blank_image() -> None:
    assert set(DETECTORS) == {"yolox-nano"}
    detector = Detector2D.load("yolox-nano")
    assert (detector.name, detector.layout, detector.class_names) == ("yolox-nano", "yolox", COCO80)
    found = detector.detect(np.full((480, 640, 3), 128, np.uint8))
    assert len(found.scores) <= 3 and (found.scores < 0.3).all()
    assert ((found.boxes >= 0) & (found.boxes <= [640, 480, 640, 480])).all()


def test_the_bundled_file_is_the_one_its_licence_describes() -> None:
    digest = hashlib.sha256((MODELS / DETECTORS["yolox-nano"]).read_bytes()).hexdigest()
    assert f"sha256 {digest}" in (MODELS / "LICENSE-YOLOX.txt").read_text()


def test_a_detector_pickles_as_what_it_was_opened_with(yolox_file: Path) -> None:
    """Ray ships the pipeline to its workers by pickle; each reopens the file."""
    copy = pickle.loads(pickle.dumps(Detector2D.load(yolox_file, threads=1)))
    assert (copy.name, copy.layout, copy.class_names) == ("tiny_yolox", "yolox", ("cat", "chair", "tv"))
    np.testing.assert_allclose(copy.detect(IMAGE).scores, [0.72, 0.3], rtol=1e-6)
