"""Post-processing: per-class selection, NMS and box decoding."""
