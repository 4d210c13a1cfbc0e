"""2D object detectors trained on real photographs (ONNX: YOLOX, NanoDet, boxes/scores/labels), their
classes mapped onto a3d's 19; ``Detector2D.load("yolox-nano").detect(rgb)``."""

from a3d.runtime.detector2d.detector import DETECTORS, Detections2D, Detector2D

__all__ = ["DETECTORS", "Detections2D", "Detector2D"]
