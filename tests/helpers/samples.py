"""The bundled samples and model, and the frozen model behind a3d-run's pinned output on them."""

from __future__ import annotations

from pathlib import Path

from a3d.runtime.models import model_path
from a3d.runtime.network.cpu_support import int8_dot_products

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "samples"
SAMPLE_MODEL = model_path()  # the bundled default model (a3d.runtime.models), a3d-run's on the samples
# The model bundled before the new world (default-world cpu-small, int8, schema 1, no score
# calibration): kept frozen so the runtime's output on the samples stays pinned to what a3d-run
# wrote before the redesign, on each kind of CPU (the int8 model's scores differ slightly
# between int8 dot products and AVX2: a3d.runtime.network.cpu_support).
PINNED_MODEL = ROOT / "tests" / "data" / "pinned_model.onnx"
PINNED_DETECTIONS = (
    ROOT / "tests" / "data" / f"samples_detections_{'int8_dot' if int8_dot_products() else 'avx2'}.jsonl"
)
