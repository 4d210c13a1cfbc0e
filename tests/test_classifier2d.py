"""a3d.runtime.classifier2d: the ImageNet -> a3d class map, crops as one batch, the classifier's second
opinion fused into the scores (a3d.runtime.postprocess.fuse), and the stage end to end in the
pipeline and a3d-run on tiny ONNX classifiers (tests/helpers/classifier_files.py)."""

from __future__ import annotations

import hashlib
import pickle
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort
import pytest

from a3d.runtime.classifier2d import CLASSIFIERS, Classifier2D
from a3d.runtime.classifier2d.class_map import IMAGENET_CLASS_MAP, first_name, label_matrix
from a3d.runtime.classifier2d.crops import crop_batch
from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.models import HERE as MODELS
from a3d.runtime.pipeline import PipelineConfig, detect_frames
from a3d.runtime.postprocess.fuse import (
    CLASSIFIER_REFERENCE,
    NETWORK,
    SECOND_OPINIONS,
    Picked,
    second_opinion,
    second_opinion_rows,
)
from a3d.runtime.sources.folder import FolderSource
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES, class_index
from tests.helpers.classifier_files import classifier_graph, constant_classifier
from tests.helpers.runtime_frames import FakeModel, write_scene_folder

DESK, PILLOW, DRESSER, CHAIR = (class_index(c) for c in ("desk", "pillow", "dresser", "chair"))
LABELS = ["background", "pillow", "desk", "tench, Tinca tinca"]


# ----------------------------------------------------------------------------- the class map


def test_the_map_names_imagenet_labels_of_the_bundled_classifier_and_a3d_classes() -> None:
    session = ort.InferenceSession(
        str(MODELS / CLASSIFIERS["mobilenet-v2"]), providers=["CPUExecutionProvider"]
    )
    labels = session.get_modelmeta().custom_metadata_map["labels"].splitlines()
    assert len(labels) == 1001 and labels[0] == "background"
    assert set(IMAGENET_CLASS_MAP) <= {first_name(label) for label in labels}  # no typo drops a class
    assert set(IMAGENET_CLASS_MAP.values()) <= set(CLASSES) - {"counter", "night stand"}


def test_a_crop_probability_of_an_a3d_class_sums_its_imagenet_classes() -> None:
    labels = (
        "background",
        "chiffonier, commode",
        "wardrobe, closet, press",
        "table lamp",
        "tench, Tinca tinca",
    )
    matrix = label_matrix(labels)
    assert matrix.shape == (5, NUM_CLASSES)
    probs = np.array([[0.1, 0.2, 0.3, 0.15, 0.25]])
    per_class = probs @ matrix
    assert per_class[0, DRESSER] == pytest.approx(0.5)
    assert per_class[0, class_index("lamp")] == pytest.approx(0.15)
    assert per_class.sum() == pytest.approx(0.65)  # background and the fish stand for no a3d class


# ----------------------------------------------------------------------------- crops


def test_a_crop_is_the_box_with_its_context_stretched_to_the_side_in_rgb_scaled_about_128() -> None:
    image = np.zeros((60, 80, 3), np.uint8)
    image[8:32, 6:50] = (255, 0, 128)  # a 44 x 24 patch in RGB
    box = [10.0, 10.0, 46.0, 30.0]  # 36 x 20, grown by 10 % on each side: [6.4, 8, 49.6, 32], the patch
    (crop,) = crop_batch(image, np.array([box]), side=16)
    assert crop.shape == (3, 16, 16) and crop.dtype == np.float32
    np.testing.assert_allclose(crop[0], 127 / 128)
    np.testing.assert_allclose(crop[1], -1.0)
    np.testing.assert_allclose(crop[2], 0.0)
    (wider,) = crop_batch(image, np.array([box]), side=16, context=0.3)
    assert wider[0].min() < 0  # more context: some of the black around the patch


def test_boxes_beyond_the_image_are_clipped_and_no_boxes_are_an_empty_batch() -> None:
    image = np.full((30, 40, 3), 200, np.uint8)
    batch = crop_batch(image, np.array([[-20.0, -5.0, 10.0, 50.0], [35.0, 25.0, 90.0, 90.0]]), side=8)
    np.testing.assert_allclose(batch, (200 - 128) / 128)
    assert crop_batch(image, np.zeros((0, 4)), side=8).shape == (0, 3, 8, 8)


# ----------------------------------------------------------------------------- the fusion


def _picked(classes: list[int], scores: list[float], sources: list[str]) -> Picked:
    return Picked(np.arange(len(classes)), np.array(classes), np.array(scores), tuple(sources))


def test_the_classifier_looks_at_the_best_own_detections_of_its_classes_only() -> None:
    picked = _picked([DESK, CHAIR, PILLOW, DESK, DRESSER], [0.2, 0.9, 0.6, 0.7, 0.8],
                     [NETWORK, NETWORK, NETWORK, "yolox-nano+network", NETWORK])  # fmt: skip
    classes = np.ones(NUM_CLASSES, bool)
    classes[CHAIR] = False  # a class the 2D detector knows
    assert second_opinion_rows(picked, classes).tolist() == [4, 2, 0]  # best first, own ones only
    assert second_opinion_rows(picked, classes, limit=2).tolist() == [4, 2]
    assert SECOND_OPINIONS >= 8


def test_the_classifier_at_its_reference_leaves_a_score_and_moves_it_either_way() -> None:
    picked = _picked([DESK, PILLOW, CHAIR, DRESSER], [0.6, 0.5, 0.4, 0.3], [NETWORK] * 4)
    chosen = np.array([0, 1, 3])
    probs = np.zeros((3, NUM_CLASSES))
    probs[0, DESK], probs[1, PILLOW], probs[2, DRESSER] = 0.001, CLASSIFIER_REFERENCE, 0.9
    probs[0, PILLOW] = 0.99  # another class's probability counts for nothing
    out = second_opinion(picked, chosen, probs, "tiny")
    by_class = dict(zip(out.class_idx.tolist(), out.scores.tolist(), strict=True))
    assert by_class[PILLOW] == pytest.approx(0.5)
    assert by_class[DESK] < 0.6 and by_class[DRESSER] > 0.3
    assert by_class[CHAIR] == 0.4  # not chosen: as it was
    sources = dict(zip(out.class_idx.tolist(), out.sources, strict=True))
    assert sources == {DESK: "network+tiny", PILLOW: "network+tiny", DRESSER: "network+tiny", CHAIR: NETWORK}
    assert np.all(np.diff(out.scores) <= 0)  # by descending score
    assert sorted(out.rows.tolist()) == [0, 1, 2, 3]


# ----------------------------------------------------------------------------- the classifier


def _colour_classifier(path: Path, input_shape: tuple = ("batch", 3, "height", "width")) -> Path:
    """Red crops are pillows, blue crops desks (RGB, (value - 128) / 128)."""
    weights = np.zeros((3, 4))
    weights[0, 1], weights[2, 2] = 8.0, 8.0
    return classifier_graph(path, LABELS, weights, np.zeros(4), input_shape)


@pytest.mark.parametrize("shape", [("batch", 3, "height", "width"), (1, 3, 24, 24)])
def test_a_crop_colour_picks_its_class_in_rgb_whatever_the_batch(tmp_path: Path, shape: tuple) -> None:
    classifier = Classifier2D.load(_colour_classifier(tmp_path / "colours.onnx", shape), threads=1)
    image = np.zeros((40, 60, 3), np.uint8)
    image[:, :30] = (255, 0, 0)
    image[:, 30:] = (0, 0, 255)
    probs = classifier.classify(image, np.array([[2.0, 2.0, 26.0, 38.0], [34.0, 2.0, 58.0, 38.0]]))
    assert probs.shape == (2, NUM_CLASSES)
    assert probs[0, PILLOW] > 0.9 and probs[1, DESK] > 0.9
    assert classifier.classes[[PILLOW, DESK]].all() and classifier.classes.sum() == 2
    assert classifier.classify(image, np.zeros((0, 4))).shape == (0, NUM_CLASSES)
    assert classifier.name == "colours"
    copy = pickle.loads(pickle.dumps(classifier))  # a Ray worker reopens it
    np.testing.assert_allclose(copy.classify(image, np.array([[2.0, 2.0, 26.0, 38.0]])), probs[:1])


def test_the_bundled_classifier_loads_by_name_and_is_the_file_its_licence_describes() -> None:
    classifier = Classifier2D.load("mobilenet-v2", threads=1)
    assert not classifier.classes[[class_index("counter"), class_index("night stand")]].any()
    assert classifier.classes.sum() == 17
    probs = classifier.classify(np.full((48, 64, 3), 128, np.uint8), np.array([[0.0, 0.0, 64.0, 48.0]]))
    assert probs.shape == (1, NUM_CLASSES) and 0 <= probs.sum() <= 1 + 1e-6
    digest = hashlib.sha256((MODELS / CLASSIFIERS["mobilenet-v2"]).read_bytes()).hexdigest()
    assert f"sha256 {digest}" in (MODELS / "LICENSE-MobileNetV2.txt").read_text()


@pytest.mark.parametrize(
    ("problem", "message"),
    [
        ("missing", "no such image classifier file"),
        ("no labels", "names no classes"),
        ("count", "3 labels in its metadata"),
        ("no a3d class", "none of its classes stands for an a3d class"),
        ("not square", "takes 24 x 32 crops"),
    ],
)
def test_bad_classifier_files_are_one_line_naming_the_file(
    tmp_path: Path, problem: str, message: str
) -> None:
    path = tmp_path / "bad.onnx"
    if problem == "no labels":
        constant_classifier(path, [""], [1.0])
    elif problem == "count":
        classifier_graph(path, LABELS[:3], np.zeros((3, 4)), np.zeros(4))
    elif problem == "no a3d class":
        constant_classifier(path, ["background", "tench"], [0.5, 0.5])
    elif problem == "not square":
        _colour_classifier(path, (1, 3, 24, 32))
    if problem == "count":  # the graph fixes 4 outputs but names 3
        import onnx

        model = onnx.load(path)
        model.graph.output[0].type.tensor_type.shape.dim[1].dim_value = 4
        onnx.save(model, path)
    with pytest.raises(InputError) as error:
        Classifier2D.load(path, threads=1)
    text = str(error.value)
    assert "\n" not in text and text.startswith(str(path)) and message in text


# ----------------------------------------------------------------------------- in the pipeline


def _run(folder: Path, config: PipelineConfig) -> list:
    return [o.detections for o in detect_frames(FolderSource(folder), FakeModel(), config)]


def test_the_pipeline_rescores_its_best_own_detections_by_the_classifier(tmp_path: Path) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    probs = [0.1, 0.01, 0.8, 0.09]  # every crop: a desk 0.8, a pillow 0.01
    classifier = Classifier2D.load(constant_classifier(tmp_path / "tiny.onnx", LABELS, probs), threads=1)
    config = PipelineConfig.from_metadata(FakeModel().metadata)
    plain, judged = _run(folder, config), _run(folder, replace(config, classifier=classifier))
    p = np.zeros(NUM_CLASSES)
    p[PILLOW], p[DESK] = 0.01, 0.8
    for own, both in zip(plain, judged, strict=True):
        assert own.sources is None and both.sources is not None
        assert "classifier2d" in both.timing
        touched = [i for i, s in enumerate(both.sources) if s == f"{NETWORK}+tiny"]
        assert set(both.sources) <= {NETWORK, f"{NETWORK}+tiny"}
        assert 0 < len(touched) <= SECOND_OPINIONS
        assert {CLASSES[both.class_ids[i]] for i in touched} <= {"pillow", "desk"}
        before = {(c, tuple(b)): s for c, b, s in zip(own.class_ids, own.boxes2d, own.scores, strict=True)}
        for i, (c, b, s) in enumerate(zip(both.class_ids, both.boxes2d, both.scores, strict=True)):
            old = before[(c, tuple(b))]
            if i in touched:
                expected = second_opinion(_picked([c], [old], [NETWORK]), np.array([0]), p[None], "tiny")
                assert s == pytest.approx(expected.scores[0])
            else:
                assert s == old


def test_a_classifier_that_fails_leaves_the_scores_and_says_so(tmp_path: Path) -> None:
    class Broken:
        name = "broken"
        classes = np.ones(NUM_CLASSES, bool)

        def classify(self, color_rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray:
            raise RuntimeError("out of memory")

    folder = write_scene_folder(tmp_path / "frames", ["a"])
    config = PipelineConfig.from_metadata(FakeModel().metadata)
    (plain,), (broken,) = _run(folder, config), _run(folder, replace(config, classifier=Broken()))
    np.testing.assert_array_equal(plain.scores, broken.scores)
    assert any("image classifier broken failed (RuntimeError: out of memory)" in n for n in broken.notes)


def test_a3d_run_classifier_flag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from a3d.runtime.cli import run as run_cli

    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: FakeModel())
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    classifier = constant_classifier(tmp_path / "tiny.onnx", LABELS, [0.1, 0.01, 0.8, 0.09])
    out = tmp_path / "det.jsonl"
    argv = [str(folder), "--headless", "--score-threshold", "0", "--output", str(out), "--detector", "none"]
    assert run_cli.main([*argv, "--classifier", str(classifier)]) == 0
    (det,) = read_detections(out)
    assert f"{NETWORK}+tiny" in det.sources


def test_the_classifier_sees_the_frame_in_rgb_and_the_boxes_it_rescores(tmp_path: Path) -> None:
    class Recorder:
        name = "recorder"
        classes = np.ones(NUM_CLASSES, bool)

        def __init__(self) -> None:
            self.seen: list[tuple[np.ndarray, np.ndarray]] = []

        def classify(self, color_rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray:
            self.seen.append((color_rgb.copy(), boxes.copy()))
            return np.full((len(boxes), NUM_CLASSES), 0.5)

    folder = write_scene_folder(tmp_path / "frames", ["a"])
    recorder = Recorder()
    config = replace(PipelineConfig.from_metadata(FakeModel().metadata), classifier=recorder)
    (det,) = _run(folder, config)
    ((image, boxes),) = recorder.seen
    np.testing.assert_array_equal(image, cv2.imread(str(det.color), cv2.IMREAD_COLOR)[..., ::-1])
    touched = [i for i, s in enumerate(det.sources) if s == f"{NETWORK}+recorder"]
    assert sorted(map(tuple, boxes)) == sorted(map(tuple, det.boxes2d[touched]))
