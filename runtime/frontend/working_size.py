"""A frame brought to the size a3d's networks were trained at before anything runs on it.

Why: a3d's networks learned from frames 640 pixels across (a3d-synth's camera presets; NYUv2's
crop is 561), and the proposal front end's settings are in pixels. A RealSense streams 1280 x 720,
a Kinect v2 or an Azure Kinect 1920 x 1080: run as they come, every object is two or three times
the size in pixels the network knows and the segments are cut for smaller objects; the same frames
brought to 640 across score far better in half the time (docs/running.md "Frames larger than 640
across"). A frame whose longer side is over ``WORKING_SIDE`` pixels is resized to it: colour by
area, depth by nearest neighbour (no depth is invented across an object's edge), intrinsics with
them. Its detections' 2D boxes go back to the frame's own pixels (``to_native``); 3D boxes are
metric and do not move. The pipeline keeps a frame that brings its own proposals, cut for its size,
as it is, unless it computes them anyway (a3d.runtime.pipeline.prepare).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from a3d.runtime.network.network_input import scale_boxes
from a3d.runtime.structures.frame import Frame

WORKING_SIDE = 640  # pixels along the longer side: a3d-synth's presets are 640 across


@dataclass(frozen=True)
class WorkingFrame:
    """``frame`` at the working size and the factors ``sx``, ``sy`` it was resized by (1: as it came)."""

    frame: Frame
    sx: float = 1.0
    sy: float = 1.0
    native_size: tuple[int, int] | None = None  # (H, W) of the frame as it came, where resized

    def to_native(self, boxes: np.ndarray) -> np.ndarray:
        """2D boxes (N, 4) in the working frame's pixels as the original frame's, inside its image
        ([-0.5, W - 0.5] across)."""
        if self.native_size is None:
            return np.asarray(boxes)
        height, width = self.native_size
        native = scale_boxes(boxes, 1.0 / self.sx, 1.0 / self.sy)
        return np.clip(native, -0.5, np.array([width, height, width, height]) - 0.5)


def working_frame(frame: Frame, side: int | None = WORKING_SIDE) -> WorkingFrame:
    """``frame`` with its longer side brought down to ``side`` pixels (module docstring), without its
    precomputed proposals (cut for its own size); as it is where it is no longer or ``side`` is None
    or 0 (a3d-run's ``--working-side 0``)."""
    height, width = frame.image_size
    if not side or max(height, width) <= side:
        return WorkingFrame(frame)
    scale = side / max(height, width)
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    sx, sy = size[0] / width, size[1] / height
    color = cv2.resize(frame.color, size, interpolation=cv2.INTER_AREA)
    depth = cv2.resize(frame.depth, size, interpolation=cv2.INTER_NEAREST)
    resized = replace(
        frame, color=color, depth=depth, intrinsics=frame.intrinsics.resized(sx, sy), proposals=None
    )
    return WorkingFrame(resized, sx, sy, (height, width))
