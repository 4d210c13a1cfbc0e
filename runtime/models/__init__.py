"""The models that install with a3d, by short name (ultralytics' "yolov8n.pt" by name, without a hub).

``live``: the small network trained from scratch on a3d-synth, fast enough for cameras at frame
rate; ``real``: the same network with a 2D detector trained on real photographs
(``PIPELINE_DETECTORS``). The models are int8 ONNX files shipped as package data beside this
module; each carries its model card in its metadata (``a3d-run --model-info NAME``). Anything
that is not a short name is a path to a model file.
"""

from __future__ import annotations

import os
from pathlib import Path

MODELS: dict[str, str] = {"live": "live.onnx", "real": "live.onnx"}
PIPELINE_DETECTORS: dict[str, str] = {"real": "yolox-nano"}
"""The bundled pipelines: a network by its short name with the 2D detector (a3d.runtime.detector2d)
whose boxes join its RoIs (and, with them, the 3D boxes are squared to the walls, doors fitted to
the depth and what stands on the floor set down on it, a3d.runtime.postprocess.wall_axes,
depth_fit and floor_contact, and the depth support of
a3d.runtime.postprocess.depth_support weighs every score). ``real`` is ``live``'s network with
YOLOX-Nano (COCO): on real rooms the detector's real-photograph training sees chairs, sofas,
tables and monitors that a network trained on synthetic rooms alone misses (docs/real-rooms.md)."""
DEFAULT_MODEL = "real"
HERE = Path(__file__).resolve().parent
NO_DETECTOR = "none"


def model_path(model: str | os.PathLike | None = None) -> Path:
    """The file of a short name (None: the default model), or ``model`` itself as a path."""
    if model is None:
        model = DEFAULT_MODEL
    if is_model_name(model):
        return HERE / MODELS[os.fspath(model)]
    return Path(model)


def is_model_name(model: str | os.PathLike | None) -> bool:
    """A short name (a path spelled as one counts: names win over files in the working folder)."""
    return model is not None and os.fspath(model) in MODELS


def pipeline_detector(
    model: str | os.PathLike | None, detector: str | os.PathLike | None = None, named: str | None = None
) -> str | os.PathLike | None:
    """The 2D detector a run uses: ``detector`` where given ("none": no detector), else the one of
    the model's bundled pipeline, else ``named``, the one the model file names (its metadata's
    ``detector``: a fine-tuned pipeline's); None for a network alone."""
    if detector is not None:
        return None if os.fspath(detector) == NO_DETECTOR else detector
    name = DEFAULT_MODEL if model is None else os.fspath(model)
    return PIPELINE_DETECTORS.get(name, named)
