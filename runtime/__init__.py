"""a3d runtime: numpy + OpenCV + ONNX Runtime + rerun only. Never imports torch."""
