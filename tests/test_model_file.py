"""The model file as the runtime opens it (a3d.runtime.network.model): metadata round trip,
integrity, refusals.

The model here is a small hand-built ONNX graph with the contract's inputs and outputs (known
answers, no torch export); tests/test_export.py covers files written by a3d-export.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from a3d.export.onnx_export import save_model
from a3d.runtime.errors import ModelError
from a3d.runtime.frontend.proposals import ProposalConfig
from a3d.runtime.network.model import (
    METADATA_KEY,
    SCHEMA_VERSION,
    DetectorModel,
    ModelMetadata,
    content_digest,
)
from a3d.runtime.network.preprocess import COLOR_MEAN_BGR, DEPTH_MEAN
from a3d.runtime.postprocess.score_calibration import ScoreCalibration
from a3d.runtime.structures.classes import CLASSES
from tests.helpers.samples import PINNED_MODEL

RNG = np.random.default_rng(7)
W_CLS = RNG.normal(size=(8, 20)).astype(np.float32)
W_3D = RNG.normal(size=(4, 140)).astype(np.float32)
W_2D = RNG.normal(size=(4, 80)).astype(np.float32)
MEAN_SIZES = RNG.uniform(0.2, 2.0, (19, 3))


def _graph_model(input_names=("color", "depth", "rois", "context_rois"), deltas3d_width=7) -> onnx.ModelProto:
    """probs = softmax([rois, context] @ W_CLS + mean(color) + mean(depth)), deltas3d = rois @ W_3D,
    deltas2d = context_rois @ W_2D, reshaped to (R, 20, k)."""
    color, depth, rois, context = input_names
    inputs = [
        helper.make_tensor_value_info(color, TensorProto.FLOAT, [1, 3, "height", "width"]),
        helper.make_tensor_value_info(depth, TensorProto.FLOAT, [1, 3, "height", "width"]),
        helper.make_tensor_value_info(rois, TensorProto.FLOAT, ["rois", 4]),
        helper.make_tensor_value_info(context, TensorProto.FLOAT, ["rois", 4]),
    ]
    outputs = [
        helper.make_tensor_value_info("class_probs", TensorProto.FLOAT, ["rois", 20]),
        helper.make_tensor_value_info("deltas3d", TensorProto.FLOAT, ["rois", 20, deltas3d_width]),
        helper.make_tensor_value_info("deltas2d", TensorProto.FLOAT, ["rois", 20, 4]),
    ]
    weights = [
        numpy_helper.from_array(W_CLS, "w_cls"),
        numpy_helper.from_array(W_3D[:, : 20 * deltas3d_width].copy(), "w_3d"),
        numpy_helper.from_array(W_2D, "w_2d"),
        numpy_helper.from_array(np.array([-1, 20, deltas3d_width], np.int64), "shape3d"),
        numpy_helper.from_array(np.array([-1, 20, 4], np.int64), "shape2d"),
    ]
    nodes = [
        helper.make_node("ReduceMean", [color], ["color_mean"], keepdims=0),
        helper.make_node("ReduceMean", [depth], ["depth_mean"], keepdims=0),
        helper.make_node("Concat", [rois, context], ["boxes"], axis=1),
        helper.make_node("MatMul", ["boxes", "w_cls"], ["logits0"]),
        helper.make_node("Add", ["logits0", "color_mean"], ["logits1"]),
        helper.make_node("Add", ["logits1", "depth_mean"], ["logits"]),
        helper.make_node("Softmax", ["logits"], ["class_probs"], axis=1),
        helper.make_node("MatMul", [rois, "w_3d"], ["flat3d"]),
        helper.make_node("Reshape", ["flat3d", "shape3d"], ["deltas3d"]),
        helper.make_node("MatMul", [context, "w_2d"], ["flat2d"]),
        helper.make_node("Reshape", ["flat2d", "shape2d"], ["deltas2d"]),
    ]
    graph = helper.make_graph(nodes, "contract", inputs, outputs, weights)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 10
    onnx.checker.check_model(model)
    return model


def _metadata(**changes) -> ModelMetadata:
    values = {
        "schema_version": SCHEMA_VERSION,
        "classes": CLASSES,
        "mean_sizes": MEAN_SIZES,
        "color_mean_bgr": tuple(float(v) for v in COLOR_MEAN_BGR),
        "depth_mean": DEPTH_MEAN,
        "depth_truncation_m": 10.0,
        "input_scale": 0.5,
        "context_scale": 1.5,
        "min_score": 0.01,
        "nms_iou": 0.3,
        "top_k": 100,
        "proposals": ProposalConfig(min_area=200, max_proposals=2000),
        "provenance": {"a3d_version": "test", "checkpoint": {"sha256": "0" * 64}},
    }
    return ModelMetadata(**{**values, **changes})


@pytest.fixture
def model_file(tmp_path: Path) -> Path:
    path = tmp_path / "model.onnx"
    save_model(_graph_model(), _metadata(), path)
    return path


def _refusal(path: Path) -> str:
    """DetectorModel.load's one-line ModelError, which names the file."""
    with pytest.raises(ModelError) as info:
        DetectorModel.load(path, threads=1)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
    return message


def test_load_round_trips_metadata_and_runs_the_graph(model_file: Path) -> None:
    written = _metadata()
    model = DetectorModel.load(model_file, threads=1)
    got = model.metadata
    assert json.loads(dataclasses.replace(got, content_sha256="").to_json()) == json.loads(
        dataclasses.replace(written, content_sha256="").to_json()
    )
    assert got.classes == CLASSES and got.mean_sizes.shape == (19, 3) and got.input_scale == 0.5
    assert got.content_sha256 == content_digest(model_file.read_bytes())
    assert ModelMetadata.from_json(got.to_json(), "again").to_json() == got.to_json()
    color = RNG.normal(size=(3, 9, 11)).astype(np.float32)
    depth = RNG.normal(size=(3, 9, 11)).astype(np.float32)
    rois, context = (RNG.uniform(0, 10, (6, 4)).astype(np.float32) for _ in range(2))
    probs, deltas3d, deltas2d = model.run(color, depth, rois, context)
    logits = np.hstack([rois, context]) @ W_CLS + color.mean() + depth.mean()
    want = np.exp(logits - logits.max(1, keepdims=True))
    np.testing.assert_allclose(probs, want / want.sum(1, keepdims=True), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(deltas3d, (rois @ W_3D).reshape(6, 20, 7), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(deltas2d, (context @ W_2D).reshape(6, 20, 4), rtol=1e-5, atol=1e-5)
    empty = model.run(color, depth, np.zeros((0, 4)), np.zeros((0, 4)))
    assert [a.shape for a in empty] == [(0, 20), (0, 20, 7), (0, 20, 4)]


def test_runtime_opens_the_file_without_onnx_or_torch(model_file: Path) -> None:
    script = textwrap.dedent(f"""
        import sys
        import numpy as np
        from a3d.runtime.network.model import DetectorModel
        model = DetectorModel.load({str(model_file)!r}, threads=1)
        probs, _, _ = model.run(np.zeros((3, 4, 4)), np.zeros((3, 4, 4)), np.ones((2, 4)), np.ones((2, 4)))
        assert probs.shape == (2, 20)
        print(sorted(m for m in ("onnx", "torch", "scipy") if m in sys.modules))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_missing_empty_truncated_and_garbage_files_are_refused(tmp_path: Path, model_file: Path) -> None:
    assert "no such model file" in _refusal(tmp_path / "absent.onnx")
    empty = tmp_path / "empty.onnx"
    empty.write_bytes(b"")
    assert "empty model file" in _refusal(empty)
    data = model_file.read_bytes()
    for cut in (len(data) // 2, len(data) - 7, 100):
        truncated = tmp_path / f"truncated{cut}.onnx"
        truncated.write_bytes(data[:cut])
        assert "truncated or corrupted" in _refusal(truncated)
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(np.random.default_rng(0).bytes(5000))
    message = _refusal(garbage)
    assert "corrupted" in message or "not an ONNX model" in message


def test_a_flipped_byte_in_the_weights_is_caught_by_the_checksum(tmp_path: Path, model_file: Path) -> None:
    data = bytearray(model_file.read_bytes())
    at = bytes(data).index(W_3D.tobytes()) + 1000  # inside w_3d's raw data: still a valid protobuf
    data[at] ^= 0x10
    corrupted = tmp_path / "corrupted.onnx"
    corrupted.write_bytes(bytes(data))
    onnx.load(str(corrupted))  # the onnx package reads it without complaint
    assert "corrupted model file" in _refusal(corrupted)


def test_a_plain_onnx_model_without_a3d_metadata_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "plain.onnx"
    onnx.save(_graph_model(), str(path))
    assert "without a3d metadata" in _refusal(path)


def _with_metadata_text(model_file: Path, out: Path, edit) -> Path:
    """A copy of ``model_file`` whose a3d metadata JSON is replaced by ``edit(dict)``."""
    model = onnx.load(str(model_file))
    entry = next(p for p in model.metadata_props if p.key == METADATA_KEY)
    data = json.loads(entry.value)
    entry.value = edit(data) if callable(edit) else edit
    onnx.save(model, str(out))
    return out


def test_metadata_of_a_newer_schema_is_refused(tmp_path: Path, model_file: Path) -> None:
    def newer(data: dict) -> str:
        data["schema_version"] = SCHEMA_VERSION + 1
        data["something_new"] = True
        return json.dumps(data)

    message = _refusal(_with_metadata_text(model_file, tmp_path / "newer.onnx", newer))
    assert f"schema version {SCHEMA_VERSION + 1} is newer" in message and "upgrade a3d" in message


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        ("{not json", "a3d metadata malformed JSON at line 1 column 2"),
        (lambda d: json.dumps({k: v for k, v in d.items() if k != "mean_sizes"}), "missing ['mean_sizes']"),
        (lambda d: json.dumps({**d, "top_k": 0}), "top_k must be a positive integer"),
        (
            lambda d: json.dumps({**d, "mean_sizes": d["mean_sizes"][:5]}),
            "mean_sizes must be a (19, 3) array",
        ),
        (lambda d: json.dumps({**d, "classes": list(reversed(d["classes"]))}), "differ from this runtime's"),
        (lambda d: json.dumps({**d, "depth_mean": 0.0}), "this runtime uses"),
    ],
)
def test_malformed_or_foreign_metadata_is_refused(
    tmp_path: Path, model_file: Path, edit, expected: str
) -> None:
    assert expected in _refusal(_with_metadata_text(model_file, tmp_path / "bad.onnx", edit))


@pytest.mark.parametrize(
    ("graph", "expected"),
    [
        (
            lambda: _graph_model(input_names=("image", "depth", "rois", "context_rois")),
            "model inputs image float",
        ),
        (
            lambda: _graph_model(deltas3d_width=6),
            "model outputs class_probs float[?,20], deltas3d float[?,20,6]",
        ),
    ],
)
def test_a_model_whose_inputs_or_outputs_differ_is_refused(tmp_path: Path, graph, expected: str) -> None:
    path = tmp_path / "other.onnx"
    save_model(graph(), _metadata(), path)
    message = _refusal(path)
    assert expected in message and "do not match the contract" in message


def test_schema_1_metadata_reads_into_todays_fields() -> None:
    """The pinned model (the one bundled before the new world) is a schema 1 file: score_threshold
    becomes min_score and the top-level max_proposals the proposal settings' cap (it overrode
    proposal_config's), one value each."""
    props = {p.key: p.value for p in onnx.load(str(PINNED_MODEL), load_external_data=False).metadata_props}
    old = json.loads(props[METADATA_KEY])
    assert old["schema_version"] == 1
    old["proposal_config"]["max_proposals"] = old["max_proposals"] + 7  # the top-level one wins
    metadata = ModelMetadata.from_json(json.dumps(old), "samples")
    assert metadata.schema_version == SCHEMA_VERSION and metadata.min_score == old["score_threshold"]
    assert metadata.proposals.max_proposals == old["max_proposals"]
    assert metadata.proposals.superpixels.n_segments == old["proposal_config"]["superpixels"]["n_segments"]
    assert metadata.score_calibration is None
    again = json.loads(metadata.to_json())
    assert "score_threshold" not in again and "max_proposals" not in again and "proposal_config" not in again
    assert ModelMetadata.from_json(metadata.to_json(), "again").proposals == metadata.proposals


CALIBRATION = ScoreCalibration(np.linspace(0.5, 2.0, 19), np.linspace(-2.0, 1.0, 19), 0.25)


def test_a_score_calibration_round_trips_and_schema_2_files_have_none(tmp_path: Path) -> None:
    path = tmp_path / "calibrated.onnx"
    save_model(_graph_model(), _metadata(score_calibration=CALIBRATION), path)
    got = DetectorModel.load(path, threads=1).metadata.score_calibration
    np.testing.assert_array_equal(got.slope, CALIBRATION.slope)
    np.testing.assert_array_equal(got.intercept, CALIBRATION.intercept)
    assert got.iou == 0.25
    schema_2 = json.loads(_metadata(content_sha256="0" * 64).to_json())
    del schema_2["score_calibration"], schema_2["pool_chunks"], schema_2["detector"]
    schema_2["schema_version"] = 2
    assert ModelMetadata.from_json(json.dumps(schema_2), "v2").score_calibration is None
    schema_2["score_calibration"] = None  # a key schema 2 did not have
    with pytest.raises(ModelError, match=r"unknown \['score_calibration'\]"):
        ModelMetadata.from_json(json.dumps(schema_2), "v2")


@pytest.mark.parametrize(
    ("key", "value", "bad", "refusal", "since"),
    [
        ("pool_chunks", 32, 0, "pool_chunks", 4),
        ("detector", "yolox-nano", " ", "detector must be a name or null", 5),
    ],
)
def test_a_newer_field_round_trips_and_older_files_do_not_say(
    key: str, value: object, bad: object, refusal: str, since: int
) -> None:
    saved = json.loads(_metadata(content_sha256="0" * 64, **{key: value}).to_json())
    assert getattr(ModelMetadata.from_json(json.dumps(saved), "new"), key) == value
    saved[key] = bad
    with pytest.raises(ModelError, match=refusal):
        ModelMetadata.from_json(json.dumps(saved), "new")
    del saved[key]
    with pytest.raises(ModelError, match=rf"missing \['{key}'\]"):
        ModelMetadata.from_json(json.dumps(saved), "new")
    saved["schema_version"] = since - 1
    for later, first in (("pool_chunks", 4), ("detector", 5)):  # nor fields of later schemas
        if first >= since:
            saved.pop(later, None)
    assert getattr(ModelMetadata.from_json(json.dumps(saved), "old"), key) is None


@pytest.mark.parametrize(
    ("calibration", "expected"),
    [
        ({"slope": [1.0] * 19, "intercept": [0.0] * 19}, "null or an object of slope, intercept and iou"),
        (
            {"slope": [1.0] * 5, "intercept": [0.0] * 19, "iou": 0.25},
            "score_calibration.slope must be a (19,)",
        ),
        ({"slope": [1.0] * 18 + [-1.0], "intercept": [0.0] * 19, "iou": 0.25}, "slope must be positive"),
        ({"slope": [1.0] * 19, "intercept": [0.0] * 19, "iou": 1.5}, "score_calibration.iou must be"),
    ],
)
def test_a_malformed_score_calibration_is_refused(
    tmp_path: Path, model_file: Path, calibration, expected
) -> None:
    edit = lambda d: json.dumps({**d, "score_calibration": calibration})  # noqa: E731
    assert expected in _refusal(_with_metadata_text(model_file, tmp_path / "bad.onnx", edit))
