"""The bundled samples and model, and the frozen model behind a3d-run's pinned output on them."""

from __future__ import annotations

from pathlib import Path

from a3d.runtime.models import model_path

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "samples"
SAMPLE_MODEL = model_path()  # the bundled default model (a3d.runtime.models), a3d-run's on the samples
# The model bundled before the new world (default-world cpu-small, int8, schema 1, no score
# calibration): kept frozen so the runtime's output on the samples stays pinned to what a3d-run
# wrote before the redesign on a CPU with int8 dot products; an AVX2-only CPU gives the same
# (its exact int8 kernel: a3d.runtime.network.model.session_options).
PINNED_MODEL = ROOT / "tests" / "data" / "pinned_model.onnx"
PINNED_DETECTIONS = ROOT / "tests" / "data" / "samples_detections.jsonl"
