"""a3d runtime: numpy + OpenCV + ONNX Runtime, and rerun for the view (optional). Never imports torch.

``from a3d.runtime import Detector`` is the Python API (a3d.runtime.detector).
"""

from a3d.runtime.detector import Detector

__all__ = ["Detector"]
