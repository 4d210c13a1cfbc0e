"""A 2D object detector trained on real photographs, run on a colour image: a3d classes and boxes.

Why: a3d's 3D networks have only seen synthetic rooms; a small detector trained on COCO finds
real chairs, sofas and tables in real frames, and the pipeline can lift its boxes into 3D. Any
ONNX file in one of the three layouts (a3d.runtime.detector2d.layouts) runs here; ``yolox-nano``
(YOLOX-Nano, COCO, Apache-2.0; runtime/models/LICENSE-YOLOX.txt) installs with a3d.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from a3d.runtime.detector2d.class_map import COCO_CLASS_MAP, CompiledMap, compile_map, read_class_map
from a3d.runtime.detector2d.decoders import decode
from a3d.runtime.detector2d.layouts import Layout, find_layout
from a3d.runtime.detector2d.names import class_names
from a3d.runtime.detector2d.preprocess import network_input
from a3d.runtime.errors import InputError
from a3d.runtime.models import HERE as MODELS_DIR
from a3d.runtime.network.model import session_options

PIPELINE_THREADS = 1
"""The detector's threads in a3d's pipeline, whatever the run's: it runs once a frame between
OpenCV's work and the network's, and on 2 cores a second thread of its own gained less than it
cost them (bench.live_rate, docs/real-rooms.md "Speed"); its threads never spin after a call."""
DETECTORS: dict[str, str] = {"yolox-nano": "yolox_nano_coco.onnx"}
"""The detectors that install with a3d (in a3d.runtime.models), by short name."""
NMS_IOU = 0.45  # YOLOX's demo


@dataclass(frozen=True)
class Detections2D:
    """One image's detections, best score first, of the classes the class map keeps."""

    boxes: np.ndarray  # (N, 4) float64 [x1, y1, x2, y2] in the input image's pixels
    scores: np.ndarray  # (N,) float64, the detector's own score
    class_ids: np.ndarray  # (N,) int64, 0-based a3d CLASSES index of the first candidate
    candidates: np.ndarray  # (N, 19) bool, the a3d classes the detector's class maps to
    names: tuple[str, ...]  # the detector's own class name of each detection


class Detector2D:
    """An ONNX 2D detector, its class names and its class map onto a3d's classes."""

    def __init__(
        self, session: ort.InferenceSession, layout: Layout, names: tuple[str, ...], class_map: CompiledMap,
        name: str, score_threshold: float,
    ) -> None:  # fmt: skip
        self._session = session
        self._layout = layout
        self._names = names
        self._map = class_map
        self._name = name
        self._threshold = score_threshold
        self._opened_as: tuple | None = None  # load()'s arguments, what a pickle reopens

    @classmethod
    def load(
        cls, spec: str | Path, *, names: Path | None = None, class_map: Path | None = None,
        threads: int = PIPELINE_THREADS,
        score_threshold: float = 0.05,
    ) -> Detector2D:  # fmt: skip
        """Open ``spec`` (a short name of DETECTORS or an ONNX path). Class names come from
        ``names`` (one per line), else the file's ``names`` metadata, else COCO's 80 for an
        80-class detector; ``class_map`` (JSON) replaces the built-in COCO map. Every problem
        is an InputError naming the file."""
        if not (isinstance(threads, int) and threads >= 1):
            raise InputError(f"threads: must be a whole number >= 1, got {threads!r}")
        if not 0.0 <= score_threshold <= 1.0:
            raise InputError(f"score_threshold: must be in 0..1, got {score_threshold!r}")
        short = os.fspath(spec) in DETECTORS
        path = MODELS_DIR / DETECTORS[os.fspath(spec)] if short else Path(spec)
        where = str(path)
        if not path.is_file():
            raise InputError(f"{where}: no such 2D detector file (short names: {', '.join(DETECTORS)})")
        options = session_options(threads)
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # PIPELINE_THREADS
        options.log_severity_level = 3  # exporters' harmless warnings (initializers listed as inputs)
        try:
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as e:  # ORT's pybind errors share no narrower base
            first = (str(e).strip().splitlines() or [type(e).__name__])[0]
            raise InputError(f"{where}: ONNX Runtime cannot load it as a 2D detector ({first})") from None
        layout = find_layout(session, where)
        metadata = session.get_modelmeta().custom_metadata_map
        detector_names = class_names(names, metadata, layout.num_classes, where)
        compiled = _compiled_map(class_map, detector_names, where)
        name = os.fspath(spec) if short else path.stem
        detector = cls(session, layout, detector_names, compiled, name, float(score_threshold))
        detector._opened_as = (spec, names, class_map, threads, float(score_threshold))
        return detector

    def __reduce__(self) -> tuple:
        """Pickled as the arguments it was loaded with (an ONNX Runtime session does not pickle):
        a Ray worker opens its own copy (a3d.runtime.scale)."""
        if self._opened_as is None:
            raise TypeError(f"{self._name}: only a 2D detector opened by Detector2D.load pickles")
        return _reopen, self._opened_as

    @property
    def name(self) -> str:
        """The short name, or the file's stem."""
        return self._name

    @property
    def layout(self) -> str:
        """The graph's output layout: "yolox", "nanodet" or "boxes"."""
        return self._layout.kind

    @property
    def classes(self) -> np.ndarray:
        """(19,) bool: the a3d classes some class of the detector stands for."""
        return self._map.candidates[self._map.kept].any(axis=0)

    @property
    def class_names(self) -> tuple[str, ...]:
        """The detector's own class names, by class index."""
        return self._names

    def detect(self, color_rgb: np.ndarray) -> Detections2D:
        """The detections of the mapped classes at or above the score threshold in an (H, W, 3)
        uint8 RGB image, after per-class NMS (IoU 0.45), boxes clipped to the image."""
        image = np.asarray(color_rgb)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
            got = f"{image.shape} {image.dtype}"
            raise InputError(f"color_rgb: expected an (H, W, 3) uint8 RGB image, got {got}")
        tensor, scale = network_input(image, self._layout)
        outputs = self._session.run(list(self._layout.outputs), {self._layout.input_name: tensor})
        decoded = decode(self._layout, outputs)
        labels = decoded.labels
        if len(labels) and not (labels.min() >= 0 and labels.max() < len(self._names)):
            bad = labels.min() if labels.min() < 0 else labels.max()
            raise ValueError(f"{self._name}: class index {bad} outside its {len(self._names)} class names")
        keep = np.flatnonzero((decoded.scores >= self._threshold) & self._map.kept[labels])
        boxes = decoded.boxes[keep] / scale
        best = _nms(boxes, decoded.scores[keep], labels[keep])
        height, width = image.shape[:2]
        keep, boxes = keep[best], np.clip(boxes[best], 0, [width, height, width, height])
        visible = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        keep, boxes = keep[visible], boxes[visible]
        labels = labels[keep]
        return Detections2D(
            boxes=boxes,
            scores=decoded.scores[keep],
            class_ids=self._map.first[labels],
            candidates=self._map.candidates[labels],
            names=tuple(self._names[i] for i in labels),
        )


def _compiled_map(class_map: Path | None, names: tuple[str, ...], where: str) -> CompiledMap:
    """The class map file's (None: the built-in COCO map) over the detector's ``names``; one that
    keeps none of them is an InputError naming the map."""
    if class_map is None:
        compiled, source = compile_map(COCO_CLASS_MAP, names), f"{where}: the built-in COCO class map"
    else:
        compiled, source = compile_map(read_class_map(class_map), names), f"{class_map}: the class map"
    if not compiled.kept.any():
        shown = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
        raise InputError(f"{source} names no class of the detector {where} (its classes: {shown})")
    return compiled


def _nms(boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Indices kept by per-class NMS at NMS_IOU, best score first (OpenCV's batched NMS)."""
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    xywh = np.concatenate([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]], axis=1)
    kept = cv2.dnn.NMSBoxesBatched(xywh, scores, labels.astype(np.int32), -np.inf, NMS_IOU)
    return np.asarray(kept, np.int64).reshape(-1)


def _reopen(
    spec: str | Path, names: Path | None, class_map: Path | None, threads: int, threshold: float
) -> Detector2D:
    return Detector2D.load(spec, names=names, class_map=class_map, threads=threads, score_threshold=threshold)
