"""The model file as the runtime sees it: one self-contained ``model.onnx`` written by a3d-export.

The graph (a3d.export.onnx_export) takes one image and its RoIs and answers per RoI:

    inputs   color (1, 3, h, w) float32         preprocess.color_input of the frame resized by input_scale
             depth (1, 3, h, w) float32         preprocess.depth_input (hole-filled depth, same size)
             rois (R, 4) float32                proposal boxes [x1, y1, x2, y2] in the RESIZED image's
             context_rois (R, 4) float32        pixel coordinates (README convention), R dynamic
    outputs  class_probs (R, 20)                softmax, index 0 = background, CLASSES[i] at i + 1
             deltas3d (R, 20, 7)                raw deltas (target normalisation folded into the
                                                weights): box_coder.decode_3d onto the initial boxes
             deltas2d (R, 20, 4)                raw Fast R-CNN deltas toward the amodal 2D box
                                                (box_coder.decode_2d)

Everything else the runtime needs travels in the file: one JSON entry under the key ``"a3d"`` in
the model's ``metadata_props`` (``ModelMetadata``), schema-versioned. ``DetectorModel.load`` checks
the file before any frame is processed and refuses it with a one-line ``ModelError`` naming the
file: missing, empty, truncated or corrupted, without a3d metadata, from a newer schema, or with
inputs/outputs other than the ones above.

Integrity: ONNX carries no checksum, and a flipped byte inside the weights still loads. The
metadata therefore holds ``content_sha256``, the SHA-256 of the file's top-level protobuf fields
other than ``metadata_props`` (field 14) in file order, i.e. the graph, weights and opsets; load
recomputes it (about 1 s per GB). The top level is walked with a few lines of protobuf wire
format below, so the runtime needs no onnx package.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from a3d.runtime.errors import ModelError
from a3d.runtime.frontend.proposals import ProposalConfig, proposal_config_from_dict
from a3d.runtime.io.json_input import is_finite_number, parse_json
from a3d.runtime.io.plain_config import plain_from_dataclass
from a3d.runtime.network.cpu_support import int8_dot_products
from a3d.runtime.network.preprocess import COLOR_MEAN_BGR, DEPTH_MEAN
from a3d.runtime.network.roi_order import POOL_CHUNKS, pooling_order
from a3d.runtime.postprocess.score_calibration import ScoreCalibration
from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES, NUM_OUTPUTS

# 2: min_score (was score_threshold), max_proposals only inside proposals; 3: score_calibration;
# 4: pool_chunks; 5: detector
SCHEMA_VERSION = 5
METADATA_KEY = "a3d"
INPUT_NAMES = ("color", "depth", "rois", "context_rois")
OUTPUT_NAMES = ("class_probs", "deltas3d", "deltas2d")
# Contract shapes: an int is a fixed size, None a free (symbolic or fixed) one.
_INPUT_SHAPES = ((1, 3, None, None), (1, 3, None, None), (None, 4), (None, 4))
_OUTPUT_SHAPES = ((None, NUM_OUTPUTS), (None, NUM_OUTPUTS, BOX_DIM), (None, NUM_OUTPUTS, 4))
_METADATA_PROPS_FIELD = 14  # ModelProto.metadata_props (repeated StringStringEntryProto {key=1, value=2})


@dataclass(frozen=True, eq=False)
class ModelMetadata:
    """What the runtime needs besides the graph (the JSON under ``metadata_props["a3d"]``).

    classes: the 19 names, softmax index i + 1 = classes[i]. mean_sizes: (19, 3) [l, w, h] metres,
    the initial 3D box size per class. color_mean_bgr, depth_mean, depth_truncation_m: the
    network inputs' preprocessing (a3d.runtime.network.preprocess). input_scale: the frame is resized by
    this factor before the network (boxes with network_input.scale_boxes); context_scale: context
    box = proposal box scaled about its centre. min_score, nms_iou, top_k: post-processing
    (docs/conventions.md "Inference and post-processing"). proposals: the proposal stage's settings the model
    was trained with, ``max_proposals`` (proposals per frame) among them, stored through the
    settings codec (a3d.runtime.io.plain_config). score_calibration: the per-class map from the
    network's score to the chance a detection is right (a3d.runtime.postprocess.score_calibration),
    None for a model that reports the softmax score as it is. pool_chunks: how many chunks of
    consecutive RoIs the graph pools apart, each on the union of its RoIs' windows, so that their
    order sets the speed (a3d.runtime.network.roi_order); 1 where the order does not matter, None
    where the file does not say (schema 1 to 3). detector: the bundled 2D detector
    (a3d.runtime.detector2d, by short name) whose boxes join this network's RoIs where a run names
    none: a fine-tuned model keeps its base pipeline's (a3d-finetune), so that running it is running
    that pipeline; None for a network alone (and schema 1 to 4). content_sha256: the integrity digest
    (module docstring). provenance: free-form (package version, training config, checkpoint hash,
    export options, verification numbers).

    Schema 1 files (``score_threshold``, ``max_proposals`` beside ``proposal_config``) are read
    into the same fields: ``min_score`` and ``proposals`` with its ``max_proposals``; schema 1
    and 2 files have no score calibration, schema 1 to 3 files no pool_chunks.
    """

    schema_version: int
    classes: tuple[str, ...]
    mean_sizes: np.ndarray
    color_mean_bgr: tuple[float, float, float]
    depth_mean: float
    depth_truncation_m: float
    input_scale: float
    context_scale: float
    min_score: float
    nms_iou: float
    top_k: int
    proposals: ProposalConfig = field(default_factory=ProposalConfig)
    score_calibration: ScoreCalibration | None = None
    pool_chunks: int | None = None
    detector: str | None = None
    content_sha256: str = ""
    provenance: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        data = {f.name: getattr(self, f.name) for f in fields(self)}
        data["classes"] = list(self.classes)
        data["mean_sizes"] = np.asarray(self.mean_sizes, np.float64).tolist()
        data["color_mean_bgr"] = [float(v) for v in self.color_mean_bgr]
        data["proposals"] = plain_from_dataclass(self.proposals)
        data["score_calibration"] = (
            None if self.score_calibration is None else self.score_calibration.to_dict()
        )
        return json.dumps(data, sort_keys=True, allow_nan=False)

    @classmethod
    def from_json(cls, text: str, where: str) -> ModelMetadata:
        """Parse and type-check; ModelError "WHERE: problem" (one line) on anything malformed."""
        data = parse_json(text, where, "a3d metadata", ModelError)
        if not isinstance(data, dict):
            raise ModelError(f"{where}: a3d metadata must be a JSON object")
        version = data.get("schema_version")
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise ModelError(f"{where}: a3d metadata has no valid schema_version (got {version!r})")
        if version > SCHEMA_VERSION:
            raise ModelError(
                f"{where}: model metadata schema version {version} is newer than this runtime's "
                f"({SCHEMA_VERSION}); upgrade a3d to run this model"
            )
        names = [f.name for f in fields(cls)]
        if version == 1:
            names = [n for n in names if n not in ("min_score", "proposals")] + list(_SCHEMA_1_KEYS)
        if version < 3:
            names.remove("score_calibration")
        if version < 4:
            names.remove("pool_chunks")
        if version < 5:
            names.remove("detector")
        missing = [n for n in names if n not in data]
        unknown = sorted(set(data) - set(names))
        if missing or unknown:
            raise ModelError(
                f"{where}: a3d metadata keys: missing {missing or 'none'}, unknown {unknown or 'none'}"
            )
        check = _Checker(where)
        if version == 1:
            data = _from_schema_1(data, check)
        sizes = check.array(data["mean_sizes"], "mean_sizes", (NUM_CLASSES, 3))
        if not np.all(sizes > 0):
            raise ModelError(f"{where}: a3d metadata mean_sizes must all be positive")
        return cls(
            schema_version=SCHEMA_VERSION,  # in memory, an older file's values are in today's fields
            classes=tuple(check.strings(data["classes"], "classes")),
            mean_sizes=sizes,
            color_mean_bgr=tuple(check.array(data["color_mean_bgr"], "color_mean_bgr", (3,)).tolist()),
            depth_mean=check.number(data["depth_mean"], "depth_mean"),
            depth_truncation_m=check.number(data["depth_truncation_m"], "depth_truncation_m", low=0.0),
            input_scale=check.number(data["input_scale"], "input_scale", low=0.0),
            context_scale=check.number(data["context_scale"], "context_scale", low=0.0),
            min_score=check.number(data["min_score"], "min_score", 0.0, 1.0, closed=True),
            nms_iou=check.number(data["nms_iou"], "nms_iou", 0.0, 1.0, closed=True),
            top_k=check.count(data["top_k"], "top_k"),
            proposals=check.proposals(data["proposals"], "proposals"),
            score_calibration=check.calibration(data.get("score_calibration"), "score_calibration"),
            pool_chunks=check.optional_count(data.get("pool_chunks"), "pool_chunks"),
            detector=check.optional_name(data.get("detector"), "detector"),
            content_sha256=check.digest(data["content_sha256"], "content_sha256"),
            provenance=check.mapping(data["provenance"], "provenance"),
        )

    def check_runtime(self, where: str) -> None:
        """Refuse a model this runtime would feed or read wrongly (classes, preprocessing constants)."""
        if self.classes != CLASSES:
            raise ModelError(f"{where}: the model's classes {list(self.classes)} differ from this runtime's")
        if not np.allclose(self.color_mean_bgr, COLOR_MEAN_BGR, rtol=0, atol=1e-4) or not math.isclose(
            self.depth_mean, DEPTH_MEAN, abs_tol=1e-4
        ):
            raise ModelError(
                f"{where}: the model expects colour mean {list(self.color_mean_bgr)} and depth mean "
                f"{self.depth_mean}; this runtime uses {COLOR_MEAN_BGR.tolist()}, {DEPTH_MEAN}"
            )


class DetectorModel:
    """A validated model file and its ONNX Runtime session (CPU, explicit thread count)."""

    def __init__(self, session: ort.InferenceSession, metadata: ModelMetadata, path: Path) -> None:
        self.session = session
        self.metadata = metadata
        self.path = path

    @classmethod
    def load(cls, path: str | os.PathLike, threads: int = 2) -> DetectorModel:
        """Read, check and open ``path``; ModelError "PATH: problem" (one line) if it is unusable."""
        path = Path(path)
        where = str(path)
        if not path.is_file():
            raise ModelError(f"{where}: no such model file")
        data = path.read_bytes()
        if not data:
            raise ModelError(f"{where}: empty model file")
        view = memoryview(data)
        records = _fields(view, 0, len(view), where)
        text = _metadata_entries(view, records, where).get(METADATA_KEY)
        if text is None:
            raise ModelError(f"{where}: an ONNX model without a3d metadata (not written by a3d-export)")
        metadata = ModelMetadata.from_json(text, where)
        if _digest(view, records) != metadata.content_sha256:
            raise ModelError(f"{where}: corrupted model file (graph and weights fail the metadata checksum)")
        metadata.check_runtime(where)
        options = session_options(threads)
        try:
            session = ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
        except Exception as e:  # ORT's pybind errors (Fail, InvalidGraph, ...) share no narrower base
            first = (str(e).strip().splitlines() or [type(e).__name__])[0]
            raise ModelError(f"{where}: ONNX Runtime cannot load the model ({first})") from None
        _check_signature(session, where)
        return cls(session, metadata, path)

    def run(
        self, color: np.ndarray, depth: np.ndarray, rois: np.ndarray, context_rois: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(probs (R, 20), deltas3d (R, 20, 7), deltas2d (R, 20, 4)) float32 for one image.

        color, depth: (3, h, w) or (1, 3, h, w) network inputs of one size; rois, context_rois:
        (R, 4) boxes in that image's pixel coordinates. R = 0 gives empty outputs.
        """
        color, depth = (np.asarray(a, np.float32) for a in (color, depth))
        color, depth = (a[None] if a.ndim == 3 else a for a in (color, depth))
        if color.shape != depth.shape or color.ndim != 4 or color.shape[:2] != (1, 3):
            raise ValueError(
                f"{self.path}: colour {color.shape} and depth {depth.shape} must be (3, h, w), one size"
            )
        rois = np.asarray(rois, np.float32)
        context_rois = np.asarray(context_rois, np.float32)
        if rois.ndim != 2 or rois.shape[1] != 4 or context_rois.shape != rois.shape:
            raise ValueError(
                f"{self.path}: rois {rois.shape}, context_rois {context_rois.shape} must be (R, 4)"
            )
        if len(rois) == 0:
            return (np.zeros((0, NUM_OUTPUTS), np.float32), np.zeros((0, NUM_OUTPUTS, BOX_DIM), np.float32),
                    np.zeros((0, NUM_OUTPUTS, 4), np.float32))  # fmt: skip
        chunks = self.metadata.pool_chunks or POOL_CHUNKS  # a file that does not say: the export's default
        # the same answers in any order; this one pools fastest (one chunk: any order is as fast)
        order = pooling_order(rois, context_rois, chunks) if chunks > 1 else np.arange(len(rois))
        feeds = dict(zip(INPUT_NAMES, (color, depth, rois[order], context_rois[order]), strict=True))
        outputs = self.session.run(list(OUTPUT_NAMES), feeds)
        back = np.empty_like(order)
        back[order] = np.arange(len(order))
        probs, deltas3d, deltas2d = (out[back] for out in outputs)
        return probs, deltas3d, deltas2d


def session_options(threads: int, flags: frozenset[str] | None = None) -> ort.SessionOptions:
    """ONNX Runtime's options for an a3d model: ``threads`` intra-op threads and one inter-op.
    Where the CPU (``flags``, default this machine's) has an int8 dot product, int8 activations
    stay int8: ONNX Runtime then runs the int8 export's pooling products (windows of a map that
    a3d-export re-quantises as int8, a3d.export.quantize.signed_pool_maps) on its uint8 x int8
    kernel, which adds exactly there. Elsewhere (x86 with AVX2 alone) that kernel adds pairs of
    products into 16-bit integers, which saturate: the bundled model scored 56.9 instead of 73.9
    on the samples. There the session asks for ONNX Runtime's uint8 x uint8 kernel
    (``session.x64quantprecision``: exact, its network stage about a fifth slower)."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    if int8_dot_products(flags):
        options.add_session_config_entry("session.qdqisint8allowed", "1")
    else:
        options.add_session_config_entry("session.x64quantprecision", "1")
    return options


def content_digest(data: bytes | memoryview, where: str = "model") -> str:
    """SHA-256 hex of a serialized ModelProto's top-level fields except metadata_props."""
    view = memoryview(data)
    return _digest(view, _fields(view, 0, len(view), where))


def _digest(view: memoryview, records: list[tuple[int, int, int, int]]) -> str:
    sha = hashlib.sha256()
    for number, start, _, end in records:
        if number != _METADATA_PROPS_FIELD:
            sha.update(view[start:end])
    return sha.hexdigest()


def _metadata_entries(view: memoryview, records: list[tuple[int, int, int, int]], where: str) -> dict:
    """The model's metadata_props as a dict (StringStringEntryProto: key = field 1, value = field 2)."""
    entries = {}
    for number, _, payload, end in records:
        if number == _METADATA_PROPS_FIELD:
            parts = {n: bytes(view[p:e]) for n, _, p, e in _fields(view, payload, end, where)}
            try:
                entries[parts.get(1, b"").decode()] = parts.get(2, b"").decode()
            except UnicodeDecodeError:
                raise ModelError(f"{where}: corrupted ONNX metadata (not UTF-8)") from None
    return entries


def _fields(view: memoryview, start: int, end: int, where: str) -> list[tuple[int, int, int, int]]:
    """(field number, record start, payload start, record end) of the protobuf fields in view[start:end]."""
    records, pos = [], start
    while pos < end:
        record = pos
        key, pos = _varint(view, pos, end, where)
        number, wire = key >> 3, key & 7
        payload = pos
        if wire == 0:
            _, pos = _varint(view, pos, end, where)
        elif wire == 1:
            pos += 8
        elif wire == 2:
            length, payload = _varint(view, pos, end, where)
            pos = payload + length
        elif wire == 5:
            pos += 4
        else:
            raise ModelError(f"{where}: not an ONNX model (protobuf wire type {wire} at byte {record})")
        if number == 0 or pos > end:
            raise ModelError(
                f"{where}: truncated or corrupted ONNX file (field at byte {record} runs past the end)"
            )
        records.append((number, record, payload, pos))
    return records


def _varint(view: memoryview, pos: int, end: int, where: str) -> tuple[int, int]:
    value = shift = 0
    while pos < end and shift < 64:
        byte = view[pos]
        value |= (byte & 0x7F) << shift
        pos += 1
        if not byte & 0x80:
            return value, pos
        shift += 7
    raise ModelError(f"{where}: truncated or corrupted ONNX file (bad varint at byte {pos})")


def _check_signature(session: ort.InferenceSession, where: str) -> None:
    """Inputs and outputs must be exactly the contract's names, float32 and shapes (module docstring)."""
    for kind, actual, names, shapes in (
        ("inputs", session.get_inputs(), INPUT_NAMES, _INPUT_SHAPES),
        ("outputs", session.get_outputs(), OUTPUT_NAMES, _OUTPUT_SHAPES),
    ):
        got = [_describe(a.name, a.type, a.shape) for a in actual]
        want = [_describe(n, "tensor(float)", s) for n, s in zip(names, shapes, strict=True)]
        ok = [a.name for a in actual] == list(names) and all(
            a.type == "tensor(float)" and _shape_fits(a.shape, s) for a, s in zip(actual, shapes, strict=True)
        )
        if not ok:
            raise ModelError(
                f"{where}: model {kind} {', '.join(got)} do not match the contract {', '.join(want)}"
            )


def _shape_fits(shape: list, expected: tuple) -> bool:
    return len(shape) == len(expected) and all(
        e is None or (isinstance(s, int) and s == e) for s, e in zip(shape, expected, strict=True)
    )


def _describe(name: str, dtype: str, shape) -> str:
    dims = ",".join("?" if d is None or isinstance(d, str) else str(d) for d in shape)
    return f"{name} {dtype.removeprefix('tensor(').rstrip(')')}[{dims}]"


_SCHEMA_1_KEYS = ("score_threshold", "max_proposals", "proposal_config")


def _from_schema_1(data: dict[str, Any], check: _Checker) -> dict[str, Any]:
    """Schema 1 metadata in schema 2's keys: the top-level proposal cap overrode the config's."""
    data = dict(data)
    cap = check.count(data.pop("max_proposals"), "max_proposals")
    proposals = check.proposals(data.pop("proposal_config"), "proposal_config")
    data["proposals"] = replace(proposals, max_proposals=cap)
    data["min_score"] = check.number(data.pop("score_threshold"), "score_threshold", 0.0, 1.0, closed=True)
    return data


class _Checker:
    """Type checks of metadata values, each raising a one-line ModelError naming the key."""

    def __init__(self, where: str) -> None:
        self.where = where

    def fail(self, key: str, want: str, value: Any) -> ModelError:
        shown = repr(value)
        return ModelError(f"{self.where}: a3d metadata {key} must be {want}, got {shown[:60]}")

    def number(self, value: Any, key: str, low: float | None = None, high: float | None = None,
               closed: bool = False) -> float:  # fmt: skip
        ok = is_finite_number(value)
        if ok and low is not None:
            ok = value >= low if closed else value > low
        if ok and high is not None:
            ok = value <= high
        if not ok:
            bounds = (
                "" if low is None else f" {'>=' if closed else '>'} {low}" + (f", <= {high}" if high else "")
            )
            raise self.fail(key, f"a finite number{bounds}", value)
        return float(value)

    def proposals(self, value: Any, key: str) -> ProposalConfig:
        if isinstance(value, ProposalConfig):  # schema 1, already converted
            return value
        return proposal_config_from_dict(value, f"{self.where}: a3d metadata {key}")

    def calibration(self, value: Any, key: str) -> ScoreCalibration | None:
        if value is None:
            return None
        if not isinstance(value, dict) or sorted(value) != ["intercept", "iou", "slope"]:
            raise self.fail(key, "null or an object of slope, intercept and iou", value)
        slope = self.array(value["slope"], f"{key}.slope", (NUM_CLASSES,))
        if not np.all(slope > 0):
            raise self.fail(f"{key}.slope", "positive numbers", value["slope"])
        intercept = self.array(value["intercept"], f"{key}.intercept", (NUM_CLASSES,))
        return ScoreCalibration(slope, intercept, self.number(value["iou"], f"{key}.iou", 0.0, 1.0))

    def count(self, value: Any, key: str) -> int:
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise self.fail(key, "a positive integer", value)
        return value

    def optional_count(self, value: Any, key: str) -> int | None:
        return None if value is None else self.count(value, key)

    def optional_name(self, value: Any, key: str) -> str | None:
        if value is None or (isinstance(value, str) and value.strip()):
            return value
        raise self.fail(key, "a name or null", value)

    def strings(self, value: Any, key: str) -> list[str]:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.fail(key, "a list of strings", value)
        return value

    def array(self, value: Any, key: str, shape: tuple[int, ...]) -> np.ndarray:
        try:
            out = np.array(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond float64
            raise self.fail(key, f"a {shape} array of numbers", value) from None
        if out.shape != shape or not np.all(np.isfinite(out)):
            raise self.fail(key, f"a {shape} array of finite numbers", value)
        out.flags.writeable = False
        return out

    def mapping(self, value: Any, key: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, "a JSON object", value)
        return value

    def digest(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or len(value) != 64 or any(c not in "0123456789abcdef" for c in value):
            raise self.fail(key, "a SHA-256 hex digest", value)
        return value
