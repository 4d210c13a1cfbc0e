"""The order in which the runtime hands RoIs to the network: neighbours share a pooling chunk.

An exported model pools its RoIs in ``POOL_CHUNKS`` chunks of consecutive rows (rows
``[i * R // n, (i + 1) * R // n)``), each chunk on the union of its RoIs' windows of the feature
map (a3d.export.roi_pool_onnx). Any order gives the same numbers; the order decides what the
unions cost. A chunk of K RoIs on an h x w window runs, per channel, K x 7 x w x h integer
multiply-adds into a K x 7 x w float intermediate that the column product reads back (K x 49 x
w multiply-adds); on a CPU with an int8 dot product the intermediate, not the arithmetic, sets
the time, so the cost counts it as ``INTERMEDIATE_COST`` multiply-adds per element:
K x w x (h + INTERMEDIATE_COST). ``pooling_order`` makes each chunk a leaf of a k-d tree on the
RoIs' corners (x1, y1, x2, y2) that cuts at the chunk boundaries; each cut sorts along the corner
whose halves' windows, of the RoIs and of their context boxes together, cost the least
(``python -m bench.roi_pool_speed`` prints the multiply-adds and the intermediate of its
order, docs/edge-speed.md "Signed windows, an order for the intermediate"). A model whose
metadata says it pools in one chunk (``pool_chunks`` 1) needs no order.
"""

from __future__ import annotations

import numpy as np

POOL_CHUNKS = 32
_CELL = 16  # image pixels per feature-map cell of the VGG16 trunks (the cost model's unit)
# Integer multiply-adds that take as long as one element of a chunk's float intermediate (written,
# read back, its 7 column multiply-adds): the pooling's time is flat for 50 to 1000 and 1 ms longer
# at 7 (docs/edge-speed.md "Signed windows, an order for the intermediate").
INTERMEDIATE_COST = 100


def chunk_bounds(count: int, chunks: int = POOL_CHUNKS) -> np.ndarray:
    """(chunks + 1,) first row of each chunk and the end, as the exported graph cuts ``count`` rows."""
    return (np.arange(chunks + 1, dtype=np.int64) * count) // chunks


def _window_cost(boxes: np.ndarray) -> np.ndarray:
    """Per candidate axis, the pooling cost of one chunk: ``boxes`` (K, axes, 4 x maps) in cells,
    the chunk's RoIs as each axis sorts them; their union window per map, K x w x (h + INTERMEDIATE_COST)."""
    low, high = boxes.min(0), boxes.max(0)  # (axes, 4 x maps)
    width = high[:, 2::4] - low[:, 0::4] + 2  # + 2: the cells that the edge samples touch
    height = high[:, 3::4] - low[:, 1::4] + 2
    return len(boxes) * (width * (height + INTERMEDIATE_COST)).sum(1)


def pooling_order(
    rois: np.ndarray, context_rois: np.ndarray | None = None, chunks: int = POOL_CHUNKS
) -> np.ndarray:
    """(R,) permutation of the rows of ``rois`` (R, 4) (and of ``context_rois``, pooled from their
    own map in the same chunks): after it, each chunk of ``chunk_bounds`` is one leaf of the k-d
    tree of the module docstring."""
    maps = [rois] if context_rois is None else [rois, context_rois]
    boxes = np.hstack([np.asarray(b, np.float64).reshape(-1, 4) for b in maps]) / _CELL
    order = np.arange(len(boxes))
    if len(boxes) <= chunks:  # at most one RoI per chunk: nothing to group
        return order
    bounds = chunk_bounds(len(boxes), chunks)
    pending = [(0, chunks)]
    while pending:
        low, high = pending.pop()
        if high - low < 2:
            continue
        middle = (low + high) // 2
        rows = order[bounds[low] : bounds[high]]
        split = bounds[middle] - bounds[low]
        by_axis = rows[np.argsort(boxes[rows, :4], axis=0, kind="stable")]  # (K, 4): sorted per corner
        sorted_boxes = boxes[by_axis]  # (K, 4 axes, 4 x maps)
        first, second = sorted_boxes[:split], sorted_boxes[split:]
        cost = _window_cost(first) + _window_cost(second)
        order[bounds[low] : bounds[high]] = by_axis[:, int(np.argmin(cost))]
        pending += [(low, middle), (middle, high)]
    return order
