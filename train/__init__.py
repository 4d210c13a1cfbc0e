"""a3d training: PyTorch data pipeline, dual-trunk RoI network and training loop."""
