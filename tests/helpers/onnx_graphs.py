"""Small ONNX graphs built in a test, run in ONNX Runtime as they are (no file)."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort


def run_graph(model: onnx.ModelProto, feeds: dict[str, np.ndarray], output: str = "out") -> np.ndarray:
    """``output`` of ``model`` on ``feeds``, on ONNX Runtime's CPU provider."""
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run([output], feeds)[0]
