"""a3d runtime: numpy + OpenCV + ONNX Runtime, and rerun for the view (optional). Never imports torch.

``from a3d.runtime import Detector, open_source`` is the Python API (a3d.runtime.detector,
a3d.runtime.sources.registry; docs/api.md).
"""

from a3d.runtime.detector import Detector
from a3d.runtime.sources.registry import SourceOptions, open_source

__all__ = ["Detector", "SourceOptions", "open_source"]
