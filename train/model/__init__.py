"""The dual-trunk VGG16 RoI network: trunks, RoI pooling, heads."""
