"""A frame's segment proposals: its precomputed ones (``NAME.proposals.npz``, e.g. MCG) when it has
them, else computed by a3d.runtime.frontend.proposals; at most ``max_proposals`` either way.

This is where runtime and training choose between the two, so both lift the same segments.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from a3d.runtime.frontend.proposals import ProposalConfig, Proposals, propose
from a3d.runtime.structures.geometry import Intrinsics

if TYPE_CHECKING:
    from a3d.runtime.sources.proposals_file import PrecomputedProposals


def frame_proposals(
    color: np.ndarray,
    filled: np.ndarray,
    intrinsics: Intrinsics,
    config: ProposalConfig,
    precomputed: PrecomputedProposals | None = None,
) -> tuple[Proposals | PrecomputedProposals | np.ndarray, np.ndarray]:
    """(segments in a form ``lift`` takes, boxes (N, 4) float64): the first ``config.max_proposals``
    of ``precomputed``, or, without them, the proposals computed from colour and filled depth."""
    if precomputed is None:
        computed = propose(color, filled, intrinsics, config)
        return computed, np.asarray(computed.boxes, np.float64)
    n = min(len(precomputed), config.max_proposals)
    boxes = np.asarray(precomputed.boxes[:n], np.float64)
    if precomputed.packed_masks is not None:
        width = precomputed.image_size[1]
        return np.unpackbits(precomputed.packed_masks[:n], axis=-1, count=width).view(bool), boxes
    assert precomputed.indptr is not None and precomputed.indices is not None
    end = int(precomputed.indptr[n])
    first = replace(
        precomputed, boxes=precomputed.boxes[:n], indptr=precomputed.indptr[: n + 1],
        indices=precomputed.indices[:end],
    )  # fmt: skip
    return first, boxes
