"""The 3D box 7-vector's layout: the one place that knows its columns.

A box is ``[x, y, z, l, w, h, theta]`` (docs/conventions.md "3D boxes"): the centre in the camera
frame, the two horizontal extents ``l >= w``, the vertical extent ``h`` and the yaw ``theta`` in the
tilt frame. Arrays of boxes are (N, ``BOX_DIM``) float64. Everything that reads or writes a column
(corners, decoding, drawing, targets, files) indexes through these names, so the layout is stated
once.
"""

from __future__ import annotations

from typing import Any

import numpy as np

BOX_DIM = 7
CENTER = slice(0, 3)  # x, y, z
SIZE = slice(3, 6)  # l, w, h
L, W, H, THETA = 3, 4, 5, 6
LOCAL_XYZ_EXTENTS = [L, H, W]  # the box's own (x, y, z) extents before its yaw: x along l, y along gravity


def boxes_array(values: Any, n: int | None = None) -> np.ndarray:
    """(N, BOX_DIM) float64 from an array-like (``n`` rows when given; N = 0 is fine)."""
    arr = np.asarray(values, dtype=np.float64)
    return arr.reshape(-1 if n is None else n, BOX_DIM)


def empty_boxes() -> np.ndarray:
    """No boxes: (0, BOX_DIM)."""
    return np.zeros((0, BOX_DIM))


def local_half_sizes(boxes: np.ndarray) -> np.ndarray:
    """(N, 3) half extents along the box's own x, y, z axes (l/2, h/2, w/2): corners and drawing."""
    return np.asarray(boxes, np.float64)[:, LOCAL_XYZ_EXTENTS] / 2.0
