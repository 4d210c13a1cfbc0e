"""File formats a3d reads and writes: images, JSON input, settings, detections lines."""
