"""a3d runtime: numpy + OpenCV + ONNX Runtime, and rerun for the view (optional). Never imports torch."""
