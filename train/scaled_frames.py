"""A training frame's colour and hole-filled depth at the network's input scale, cached on disk.

Why: without augmentation (``data.augment`` off) a training image is the same pixels in every
epoch, yet each batch decoded the frame's colour and depth PNGs and loaded its full-size filled
depth again, then resized them. On a 2-core host at 4 images a batch that loading took about a
third of the run: 2.7 iterations per second against 4.0 for the SGD step alone
(``python -m bench.train_speed``). The resized pair is written once, beside the frame's proposals
and filled depth in the RoI database's cache and under the same key (a changed frame misses), as
``NAME-KEY.scale<S>.npz``: about a quarter of the filled depth's bytes at scale 0.5.

A horizontal flip commutes with the resize (an area average of mirrored pixels), so a flipped
frame is flipped after it: the inputs equal ``frame_network_inputs``' of the flipped full-size
frame, exactly where the scale is an integer factor (0.5 of an even size) and up to float
rounding otherwise (one level of a uint8 colour at most).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3d.runtime.io.atomic import atomic_write
from a3d.runtime.network.network_input import resize_to_scale, resized_network_inputs
from a3d.runtime.sources.folder import read_frame
from a3d.train.roidb import FILLED_DEPTH_SUFFIX, UNREADABLE_CACHE, FrameRois


@dataclass(frozen=True)
class ScaledFrame:
    color: np.ndarray  # (h, w, 3) uint8 BGR at the input scale
    depth: np.ndarray  # (h, w) float32 metres, hole-filled, at the input scale
    native_size: tuple[int, int]  # the frame's own (H, W), which its RoI boxes are in

    def flipped(self) -> ScaledFrame:
        return ScaledFrame(self.color[:, ::-1], self.depth[:, ::-1], self.native_size)

    def network_inputs(
        self, boxes: np.ndarray, truncation: float, context_scale: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``frame_network_inputs`` of the full-size frame and ``boxes`` (N, 4, native pixels)."""
        return resized_network_inputs(
            self.color, self.depth, self.native_size, boxes, truncation, context_scale
        )


def scaled_frame_path(record: FrameRois, scale: float) -> Path:
    """Beside the record's filled depth (``NAME-KEY.filled.npy`` -> ``NAME-KEY.scale0.5.npz``)."""
    stem = record.filled_depth_path.name.removesuffix(FILLED_DEPTH_SUFFIX)
    return record.filled_depth_path.with_name(f"{stem}.scale{scale:g}.npz")


def load_scaled_frame(record: FrameRois, scale: float) -> ScaledFrame:
    """The record's frame at ``scale`` from the cache, or read, resized and cached (atomically, so
    DataLoader workers racing on one frame each write a whole file)."""
    path = scaled_frame_path(record, scale)
    try:
        with np.load(path) as z:
            color, depth = z["color"], z["depth"]
        return ScaledFrame(color, depth, record.image_size)
    except UNREADABLE_CACHE:
        pass  # missing or unreadable (a file cut short): computed again
    frame = read_frame(record.ref, record.folder_intrinsics)
    color, depth = resize_to_scale(frame.color, np.load(record.filled_depth_path), scale)
    atomic_write(path, lambda f: np.savez(f, color=color, depth=depth))
    return ScaledFrame(color, depth, record.image_size)
