"""a3d export: trained checkpoint -> self-contained model.onnx."""
