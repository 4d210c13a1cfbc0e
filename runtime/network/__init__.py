"""The network: the model file, its input tensors, ONNX Runtime inference."""
