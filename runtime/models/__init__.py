"""The models that install with a3d, by short name (ultralytics' "yolov8n.pt" by name, without a hub).

``live``: the small network trained from scratch on a3d-synth, fast enough for cameras at frame
rate. The models are int8 ONNX files shipped as package data beside this module; each carries
its model card in its metadata (``a3d-run --model-info NAME``). Anything that is not a short name
is a path to a model file.
"""

from __future__ import annotations

import os
from pathlib import Path

MODELS: dict[str, str] = {"live": "live.onnx"}
DEFAULT_MODEL = "live"
HERE = Path(__file__).resolve().parent


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
