"""The order in which the runtime hands RoIs to the network: neighbours share a pooling chunk.

An exported model pools its RoIs in ``POOL_CHUNKS`` chunks of consecutive rows (rows
``[i * R // n, (i + 1) * R // n)``), each chunk on the union of its RoIs' windows of the feature
map (a3d.export.roi_pool_onnx). Any order gives the same numbers; the order decides how much
arithmetic the unions cost. ``pooling_order`` makes each chunk a leaf of a k-d tree on the boxes'
corners (x1, y1, x2, y2): RoIs of one chunk are close in position and in size, so their union is
not much more than each window. On 500 proposal-like RoIs of the paper's frame it cuts the window
products' multiply-adds from 2.08 to 0.85 GMAC per map (``python -m bench.roi_pool_speed``,
docs/edge-speed.md "Where the head loses time").
"""

from __future__ import annotations

import numpy as np

POOL_CHUNKS = 32


def chunk_bounds(count: int, chunks: int = POOL_CHUNKS) -> np.ndarray:
    """(chunks + 1,) first row of each chunk and the end, as the exported graph cuts ``count`` rows."""
    return (np.arange(chunks + 1, dtype=np.int64) * count) // chunks


def pooling_order(rois: np.ndarray, chunks: int = POOL_CHUNKS) -> np.ndarray:
    """(R,) permutation of the rows of ``rois`` (R, 4): after it, each chunk of ``chunk_bounds`` is
    one leaf of a k-d tree that splits the corners at a chunk boundary along their widest axis."""
    corners = np.asarray(rois, np.float64).reshape(-1, 4)
    order = np.arange(len(corners))
    if len(corners) <= chunks:  # at most one RoI per chunk: nothing to group
        return order
    bounds = chunk_bounds(len(corners), chunks)
    pending = [(0, chunks)]
    while pending:
        low, high = pending.pop()
        if high - low < 2:
            continue
        middle = (low + high) // 2
        rows = order[bounds[low] : bounds[high]]
        points = corners[rows]
        axis = int(np.argmax(np.ptp(points, axis=0)))
        split = bounds[middle] - bounds[low]
        order[bounds[low] : bounds[high]] = rows[np.argpartition(points[:, axis], split - 1)]
        pending += [(low, middle), (middle, high)]
    return order
