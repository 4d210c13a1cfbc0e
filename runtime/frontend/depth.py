"""Depth-map hole filling for the depth trunk's input and for lifting segments that have no raw depth.

Sensor depth has holes (0 = missing): shadows beside occluding edges, dark, shiny or far surfaces.
The network needs a dense map, so holes are filled by OpenCV's Navier-Stokes inpainting (its Telea
variant is broken on float32 input in OpenCV 5), run at reduced resolution (the cost grows with
the hole area) and upsampled back *only into the holes*: valid pixels keep their exact value.

Edge awareness: structured-light and time-of-flight sensors leave a shadow hole beside an
occluding edge, on the side of the farther surface, and bordered along the image row by the near
surface on one side and the far one on the other. Averaging both sides would invent a surface in
mid-air, so a hole pixel whose nearest valid left and right neighbours (same row) differ by more
than `edge_jump` (relative), in a run of holes at most `max_shadow_px` wide, takes the farther
of the two; every other hole pixel takes the inpainted value.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.errors import InputError


@dataclass(frozen=True)
class FillConfig:
    """Hole-filling parameters. `scale`: inpainting runs at 1/scale resolution; `radius`: the
    inpainting neighbourhood (reduced pixels); `edge_jump`: relative depth step between a hole's
    left and right borders that marks it as an occlusion shadow (filled from the far side);
    `max_shadow_px`: wider runs of holes are not shadows (full-resolution pixels)."""

    scale: int = 4
    radius: float = 3.0
    edge_jump: float = 0.1
    max_shadow_px: int = 48


@dataclass(frozen=True)
class FilledDepth:
    """A filled depth map (H, W) float32 metres and what was done to get it.

    `empty` is True when the input had no valid pixel at all: then `depth` is all zeros (there is
    nothing to fill from) and callers must treat the frame as depth-less.
    """

    depth: np.ndarray
    hole_fraction: float
    empty: bool


def check_depth(depth: np.ndarray, what: str = "depth") -> np.ndarray:
    """Validate an (H, W) metric depth map (finite, >= 0; 0 = missing); returns it as float32.

    `what` names the map in the error (a file path where the caller knows it)."""
    if depth.ndim != 2:
        raise InputError(f"{what}: expected an (H, W) depth map, got shape {depth.shape}")
    depth = np.asarray(depth, dtype=np.float32)
    if not np.isfinite(depth).all():
        raise InputError(f"{what}: depth contains NaN or inf (use 0 for missing)")
    if (depth < 0).any():
        raise InputError(f"{what}: depth contains negative values (use 0 for missing)")
    return depth


def fill_depth_info(depth: np.ndarray, config: FillConfig = FillConfig()) -> FilledDepth:
    """Fill the holes (zeros) of a metric depth map; valid pixels are returned unchanged."""
    depth = check_depth(depth)
    holes = depth <= 0
    n_holes = int(holes.sum())
    if n_holes == 0:
        return FilledDepth(depth.copy(), 0.0, False)
    if n_holes == depth.size:
        return FilledDepth(np.zeros_like(depth), 1.0, True)

    h, w = depth.shape
    s = max(1, int(config.scale))
    hs, ws = -(-h // s), -(-w // s)
    # Pad to whole s x s blocks (padding counts as hole), then valid-weighted block means:
    # a reduced pixel is a hole only if its whole block is.
    pad = (0, hs * s - h, 0, ws * s - w)
    padded = cv2.copyMakeBorder(depth, *pad, cv2.BORDER_CONSTANT, value=0)
    weight = cv2.resize((padded > 0).astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA)
    small = cv2.resize(padded, (ws, hs), interpolation=cv2.INTER_AREA)
    small_holes = weight <= 0
    small = np.where(small_holes, 0.0, small / np.maximum(weight, 1e-12)).astype(np.float32)
    filled_small = cv2.inpaint(small, small_holes.view(np.uint8), config.radius, cv2.INPAINT_NS)
    up = cv2.resize(filled_small, (ws * s, hs * s), interpolation=cv2.INTER_LINEAR)[:h, :w]
    out = depth.copy()
    left, right, gap = _row_neighbours(depth, holes)
    near, far = np.minimum(left, right), np.maximum(left, right)
    shadow = (near > 0) & (far > near * (1.0 + config.edge_jump)) & (gap <= config.max_shadow_px)
    out[holes] = np.where(shadow, far, up[holes])
    # Bilinear upsampling only mixes positive values, but guard the contract (no zeros left).
    bad = holes & ~(out > 0)
    if bad.any():
        out[bad] = float(np.median(depth[~holes]))
    return FilledDepth(out, n_holes / depth.size, False)


def fill_depth(depth: np.ndarray, config: FillConfig = FillConfig()) -> np.ndarray:
    """(H, W) float32 metres, 0 = missing -> (H, W) float32 with no zeros left.

    An all-zero frame comes back all zeros (see FilledDepth.empty); never NaN.
    """
    return fill_depth_info(depth, config).depth


def _row_neighbours(values: np.ndarray, holes: np.ndarray) -> tuple[np.ndarray, ...]:
    """For each hole pixel (in the row-major order of values[holes]): the values of the nearest
    non-hole pixels to its left and right in the same row (0 where the row has none on that side)
    and the length of the run of holes it lies in. Computed per run of holes, then repeated."""
    h, w = holes.shape
    edges = np.zeros((h, w + 2), np.int8)
    edges[:, 1:-1] = holes
    step = np.diff(edges, axis=1)  # +1 where a run starts at column j, -1 where one ends before j
    rows, cols = np.nonzero(step)
    starts, ends = cols[0::2], cols[1::2]  # runs alternate start, end within each row
    rows = rows[0::2]
    padded = np.zeros((h, w + 2), values.dtype)  # column j of values is column j + 1 here
    padded[:, 1:-1] = values
    lengths = ends - starts
    left, right = padded[rows, starts], padded[rows, ends + 1]
    return np.repeat(left, lengths), np.repeat(right, lengths), np.repeat(lengths, lengths)
