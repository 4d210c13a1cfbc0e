"""An ImageNet image classifier run on boxes of a colour image: per box a probability of each a3d class.

Why: a3d's network has only seen synthetic rooms, and a COCO detector (a3d.runtime.detector2d) knows
only 7 of a3d's 19 classes. An ImageNet classifier knows real dressers, lamps, pillows, boxes and
doors; its view of a3d's own detection boxes is a second opinion on their scores
(a3d.runtime.postprocess.fuse.second_opinion). ``mobilenet-v2`` (MobileNetV2, ImageNet, Apache-2.0;
runtime/models/LICENSE-MobileNetV2.txt; made by bench.mobilenet_conversion) installs with a3d. Any
ONNX file runs that takes (N, 3, H, W) float RGB as ``(value - 128) / 128``, outputs (N, L)
probabilities (its softmax inside) and names its L classes in its metadata (``labels``, one per
line, ImageNet's spellings: a3d.runtime.classifier2d.class_map).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnxruntime as ort

from a3d.runtime.classifier2d.class_map import label_matrix
from a3d.runtime.classifier2d.crops import crop_batch
from a3d.runtime.errors import InputError
from a3d.runtime.models import HERE as MODELS_DIR
from a3d.runtime.network.model import session_options

CLASSIFIERS: dict[str, str] = {"mobilenet-v2": "mobilenet_v2_imagenet.onnx"}
"""The classifiers that install with a3d (in a3d.runtime.models), by short name."""
SIDE = 160  # crop side for a graph that takes any size: MobileNetV2 at half of 224's cost
LABELS_KEY = "labels"


class Classifier2D:
    """An ONNX image classifier and the map of its classes onto a3d's."""

    def __init__(self, session: ort.InferenceSession, side: int, batched: bool, matrix: np.ndarray,
                 name: str) -> None:  # fmt: skip
        self._session = session
        self._input = session.get_inputs()[0].name
        self._side = side
        self._batched = batched
        self._matrix = matrix
        self._name = name
        self._opened_as: tuple | None = None  # load()'s arguments, what a pickle reopens

    @classmethod
    def load(cls, spec: str | Path, *, threads: int = 2) -> Classifier2D:
        """Open ``spec`` (a short name of CLASSIFIERS or an ONNX path); every problem is an
        InputError naming the file."""
        if not (isinstance(threads, int) and threads >= 1):
            raise InputError(f"threads: must be a whole number >= 1, got {threads!r}")
        short = os.fspath(spec) in CLASSIFIERS
        path = MODELS_DIR / CLASSIFIERS[os.fspath(spec)] if short else Path(spec)
        where = str(path)
        if not path.is_file():
            shown = ", ".join(CLASSIFIERS)
            raise InputError(f"{where}: no such image classifier file (short names: {shown})")
        options = session_options(threads)
        options.log_severity_level = 3
        try:
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as e:  # ORT's pybind errors share no narrower base
            first = (str(e).strip().splitlines() or [type(e).__name__])[0]
            raise InputError(f"{where}: ONNX Runtime cannot load it as a classifier ({first})") from None
        side, batched, outputs = _shape(session, where)
        labels = tuple(session.get_modelmeta().custom_metadata_map.get(LABELS_KEY, "").splitlines())
        if not labels:
            raise InputError(f"{where}: the classifier names no classes (metadata {LABELS_KEY!r})")
        if outputs is not None and outputs != len(labels):
            raise InputError(f"{where}: {outputs} class scores but {len(labels)} labels in its metadata")
        matrix = label_matrix(labels)
        if not matrix.any():
            raise InputError(f"{where}: none of its classes stands for an a3d class (first: {labels[0]!r})")
        name = os.fspath(spec) if short else path.stem
        classifier = cls(session, side, batched, matrix, name)
        classifier._opened_as = (spec, threads)
        return classifier

    def __reduce__(self) -> tuple:
        """Pickled as the arguments it was loaded with (a Ray worker opens its own copy)."""
        if self._opened_as is None:
            raise TypeError(f"{self._name}: only an image classifier opened by Classifier2D.load pickles")
        return _reopen, self._opened_as

    @property
    def name(self) -> str:
        """The short name, or the file's stem."""
        return self._name

    @property
    def classes(self) -> np.ndarray:
        """(19,) bool: the a3d classes some class of the classifier stands for."""
        return self._matrix.any(axis=0)

    def classify(self, color_rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(N, 19) float64: per [x1, y1, x2, y2] box of an (H, W, 3) uint8 RGB image, the
        probability of each a3d class (its classes' sum; 0 for a class none stands for)."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        if not len(boxes):
            return np.zeros((0, self._matrix.shape[1]))
        batch = crop_batch(color_rgb, boxes, self._side)
        if self._batched:
            probs = self._session.run(None, {self._input: batch})[0]
        else:
            probs = np.concatenate([self._session.run(None, {self._input: crop[None]})[0] for crop in batch])
        expected = (len(boxes), self._matrix.shape[0])
        if probs.shape != expected:
            raise ValueError(f"{self._name}: output of shape {probs.shape}, expected {expected}")
        return np.asarray(probs, np.float64) @ self._matrix


def _shape(session: ort.InferenceSession, where: str) -> tuple[int, bool, int | None]:
    """(crop side, whether the graph takes a batch, its class count where it fixes one)."""
    inputs, outputs = session.get_inputs(), session.get_outputs()
    shape = inputs[0].shape if len(inputs) == 1 else []
    if len(shape) != 4 or inputs[0].type != "tensor(float)" or shape[1] not in (3, "3") or len(outputs) != 1:
        raise InputError(f"{where}: an image classifier takes one float (N, 3, H, W) input and gives one "
                         "(N, classes) output")  # fmt: skip
    height, width = shape[2:]
    fixed = isinstance(height, int) and isinstance(width, int)
    if fixed and height != width:
        raise InputError(f"{where}: the classifier takes {height} x {width} crops; a3d's crops are square")
    out = outputs[0].shape
    classes = out[-1] if len(out) == 2 and isinstance(out[-1], int) else None
    return (height if fixed else SIDE), shape[0] != 1, classes


def _reopen(spec: str | Path, threads: int) -> Classifier2D:
    return Classifier2D.load(spec, threads=threads)
