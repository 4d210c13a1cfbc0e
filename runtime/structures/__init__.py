"""Pure numpy structures and geometry: classes, boxes, cameras, detections."""
