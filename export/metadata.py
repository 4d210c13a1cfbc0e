"""ModelMetadata from a training checkpoint: everything the runtime needs besides the graph.

Values come from the checkpoint (classes, mean sizes, training config) through
``TrainConfig.pipeline`` (the runtime pipeline settings the pure-torch validation detector of
a3d.train.inference uses, so a3d-run reproduces it) and from the shared preprocessing constants
(a3d.runtime.network.preprocess), never typed in twice. ``min_score`` can be set at export
(``--score-threshold``).
"""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from a3d.export.base import ExportError
from a3d.runtime.network.model import SCHEMA_VERSION, ModelMetadata
from a3d.runtime.network.preprocess import COLOR_MEAN_BGR, DEPTH_MEAN
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES
from a3d.train.checkpoint import file_sha256
from a3d.train.config import TrainConfig
from a3d.train.model.weights import IMAGENET_VGG16_NOTICE

METRICS_FILE = "metrics.jsonl"  # a3d.train.loop writes it next to checkpoint.pt


def build_metadata(
    state: dict,
    config: TrainConfig,
    checkpoint: str | os.PathLike,
    *,
    min_score: float | None = None,
    pool_chunks: int | None = None,
    export_options: dict[str, Any] | None = None,
) -> ModelMetadata:
    """Metadata for the model exported from checkpoint ``state`` (as load_checkpoint returns it).

    ``pool_chunks``: the chunks the exported graph pools RoIs in (a3d.export.roi_pool_onnx).
    ``export_options`` (opset, int8, svd rank, ...) go into the provenance as they are.
    """
    path = Path(checkpoint)
    classes = tuple(state.get("classes", CLASSES))
    if classes != CLASSES:
        raise ExportError(f"{path}: checkpoint classes {list(classes)} are not a3d's 19 classes")
    sizes = np.asarray(state["mean_sizes"], np.float64)
    if sizes.shape != (NUM_CLASSES, 3) or not np.all(np.isfinite(sizes) & (sizes > 0)):
        raise ExportError(f"{path}: checkpoint mean_sizes must be positive, shape (19, 3), got {sizes.shape}")
    pipeline = config.pipeline(sizes)  # the runtime settings a3d.train validates with
    return ModelMetadata(
        schema_version=SCHEMA_VERSION,
        classes=CLASSES,
        mean_sizes=sizes,
        color_mean_bgr=tuple(float(str(v)) for v in COLOR_MEAN_BGR),  # shortest decimals of the float32s
        depth_mean=float(DEPTH_MEAN),
        depth_truncation_m=float(pipeline.depth_truncation_m),
        input_scale=float(pipeline.input_scale),
        context_scale=float(pipeline.context_scale),
        min_score=float(pipeline.min_score if min_score is None else min_score),
        nms_iou=float(pipeline.nms_iou),
        top_k=int(pipeline.top_k),
        proposals=pipeline.proposals,
        pool_chunks=pool_chunks,
        provenance=provenance(state, config, path, export_options or {}),
    )


def provenance(state: dict, config: TrainConfig, checkpoint: Path, export_options: dict[str, Any]) -> dict:
    """Where the model came from: package versions, date, checkpoint hash, training config and data, and
    the licence of third-party weights it was initialised from (ImageNet VGG16: CC BY 4.0, attributed)."""
    return {
        "a3d_version": _version("a3d"),
        "exported_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "checkpoint": {
            "path": str(checkpoint.resolve()),
            "sha256": file_sha256(checkpoint),
            "iteration": int(state["iteration"]),
            **({"averaged": state["averaged"]} if "averaged" in state else {}),
        },
        "training_config": config.to_dict(),
        **({"weights_licence": IMAGENET_VGG16_NOTICE} if config.solver.pretrained else {}),
        "training_data": training_data(state, checkpoint),
        "export": {**export_options, **{name: _version(name) for name in ("torch", "onnx", "onnxruntime")}},
    }


def training_data(state: dict, checkpoint: Path) -> dict | None:
    """The training set's description: the checkpoint's ``data`` entry (path, frames) when it has
    one, else the run's last ``"kind": "data"`` metrics line (frame and RoI counts), else None."""
    if isinstance(state.get("data"), dict):
        return state["data"]
    metrics = checkpoint.parent / METRICS_FILE
    found = None
    if metrics.is_file():
        for line in metrics.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(record, dict) and record.get("kind") == "data":
                found = {k: v for k, v in record.items() if k not in ("kind", "iter")}
    return found


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None
