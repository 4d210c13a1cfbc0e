"""Precomputed segment proposals, ``NAME.proposals.npz`` (README "Precomputed proposals").

A frame may bring its own proposals (MCG candidates, say) in place of a3d's proposal stage. The
archive's array shapes are checked from their ``.npy`` headers before anything is loaded.
"""

from __future__ import annotations

import io
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import atomic_write_bytes
from a3d.runtime.io.npy import npy_header

MAX_PROPOSALS = 100_000

_PROPOSAL_MEMBERS = ("boxes", "scores", "masks", "superpixels", "indptr", "indices")
# What zipfile raises for a damaged archive: bad structure or CRC, a cut file, corrupt deflate
# data, an unknown compression method (NotImplementedError), an encrypted member (RuntimeError),
# a member name that is not UTF-8 (ValueError).
_ZIP_ERRORS = (
    zipfile.BadZipFile,
    OSError,
    EOFError,
    zlib.error,
    NotImplementedError,
    RuntimeError,
    ValueError,
)


@dataclass(frozen=True)
class PrecomputedProposals:
    """Proposals read from ``NAME.proposals.npz`` (README "Precomputed proposals").

    ``boxes`` (N, 4) float32 in README pixel coordinates; ``scores`` (N,) float32 or None. The
    segments come in one of two forms: ``packed_masks`` (N, H, ceil(W / 8)) uint8, the masks
    packed along rows with ``np.packbits`` (big-endian bit order); or ``superpixels`` (H, W)
    int32 ids in [0, S) with CSR ``indptr`` (N + 1,) int64 / ``indices`` (nnz,) int32: segment i
    is the union of superpixels ``indices[indptr[i]:indptr[i + 1]]``.
    """

    boxes: np.ndarray
    image_size: tuple[int, int]
    scores: np.ndarray | None = None
    packed_masks: np.ndarray | None = None
    superpixels: np.ndarray | None = None
    indptr: np.ndarray | None = None
    indices: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.boxes)

    def mask(self, i: int) -> np.ndarray:
        """Segment ``i`` as an (H, W) bool mask."""
        if self.packed_masks is not None:
            return np.unpackbits(self.packed_masks[i], axis=-1, count=self.image_size[1]).astype(bool)
        assert self.superpixels is not None and self.indptr is not None and self.indices is not None
        members = np.zeros(int(self.superpixels.max()) + 1, dtype=bool)
        members[self.indices[self.indptr[i] : self.indptr[i + 1]]] = True
        return members[self.superpixels]

    @classmethod
    def from_masks(cls, boxes: Any, masks: np.ndarray, scores: Any = None) -> PrecomputedProposals:
        """Pack (N, H, W) bool masks."""
        masks = np.asarray(masks, dtype=bool)
        return cls(
            boxes=np.asarray(boxes, np.float32).reshape(-1, 4),
            image_size=(masks.shape[1], masks.shape[2]),
            scores=None if scores is None else np.asarray(scores, np.float32),
            packed_masks=np.packbits(masks, axis=-1),
        )


def write_precomputed_proposals(path: str | os.PathLike, proposals: PrecomputedProposals) -> None:
    """Write ``proposals`` as a compressed ``.npz`` (atomically)."""
    arrays = {key: getattr(proposals, "packed_masks" if key == "masks" else key) for key in _PROPOSAL_MEMBERS}
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{key: value for key, value in arrays.items() if value is not None})
    atomic_write_bytes(path, buffer.getvalue())


def read_precomputed_proposals(path: str | os.PathLike, image_size: tuple[int, int]) -> PrecomputedProposals:
    """Read and validate ``NAME.proposals.npz`` for an image of ``image_size`` (H, W).

    Array shapes are checked from the ``.npy`` headers inside the archive before anything is
    loaded, so a file cannot make the reader allocate more than its image size allows.
    """
    path = Path(path)
    height, width = image_size
    try:
        with zipfile.ZipFile(path) as archive:
            headers = {}
            for member in archive.namelist():
                key = member.removesuffix(".npy")
                if key not in _PROPOSAL_MEMBERS or not member.endswith(".npy"):
                    raise InputError(
                        f"{path}: unknown array {member!r} (expected: {', '.join(_PROPOSAL_MEMBERS)})"
                    )
                with archive.open(member) as f:
                    headers[key] = npy_header(f, path)[:2]
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except InputError:
        raise
    except _ZIP_ERRORS as error:
        raise InputError(f"{path}: not a readable .npz archive ({error})") from None
    if "boxes" not in headers:
        raise InputError(f"{path}: has no 'boxes' array")
    superpixel_keys = {"superpixels", "indptr", "indices"} & headers.keys()
    if not (
        ("masks" in headers and not superpixel_keys) or ("masks" not in headers and len(superpixel_keys) == 3)
    ):
        raise InputError(f"{path}: needs either 'masks' or all of 'superpixels', 'indptr', 'indices'")
    n = headers["boxes"][0][0] if len(headers["boxes"][0]) == 2 else -1
    if not 0 <= n <= MAX_PROPOSALS:
        raise InputError(
            f"{path}: boxes has shape {headers['boxes'][0]}; expected (N, 4) with N <= {MAX_PROPOSALS}"
        )
    expected = {"boxes": ((n, 4), "f"), "scores": ((n,), "f"), "masks": ((n, height, (width + 7) // 8), "u")}
    expected |= {"superpixels": ((height, width), "iu"), "indptr": ((n + 1,), "iu"), "indices": (None, "iu")}
    for key, (shape, dtype) in headers.items():
        want_shape, kinds = expected[key]
        ok_shape = shape == want_shape if want_shape is not None else len(shape) == 1
        if not ok_shape or dtype.kind not in kinds or (key == "masks" and dtype != np.uint8):
            raise InputError(f"{path}: {key} is {dtype} {shape}; expected {_expected_text(key, want_shape)}")
    return _load_proposals(path, image_size, headers)


def _expected_text(key: str, shape: tuple[int, ...] | None) -> str:
    kind = {"boxes": "float", "scores": "float", "masks": "uint8"}.get(key, "integer")
    return f"{kind} {shape if shape is not None else '(nnz,)'}"


def _load_proposals(path: Path, image_size: tuple[int, int], headers: dict) -> PrecomputedProposals:
    height, width = image_size

    def load(archive: zipfile.ZipFile, key: str) -> np.ndarray:
        try:
            with archive.open(f"{key}.npy") as f:
                return np.lib.format.read_array(f, allow_pickle=False)
        except _ZIP_ERRORS as error:
            raise InputError(f"{path}: cannot load {key} ({error})") from None

    # The members are read as the header pass read them (np.load would look at the file's first
    # bytes instead, and take a zip with data in front of it for a pickle).
    with zipfile.ZipFile(path) as npz:
        arrays: dict[str, np.ndarray] = {}
        if "superpixels" in headers:  # bounds the size of indices before it is loaded
            superpixels = arrays["superpixels"] = load(npz, "superpixels")
            if superpixels.min(initial=0) < 0 or superpixels.max(initial=0) >= 2**31:
                raise InputError(f"{path}: superpixels must hold ids in [0, 2^31)")
            nnz = headers["indices"][0][0]
            if nnz > headers["boxes"][0][0] * (int(superpixels.max(initial=0)) + 1):
                raise InputError(f"{path}: indices has {nnz} entries, more than N x superpixels")
        arrays |= {key: load(npz, key) for key in headers if key not in arrays}
    boxes = arrays["boxes"].astype(np.float32)
    if not np.isfinite(boxes).all():
        raise InputError(f"{path}: boxes has non-finite values")
    eps = 1e-3
    inside = (
        (boxes[:, 0] >= -0.5 - eps)
        & (boxes[:, 1] >= -0.5 - eps)
        & (boxes[:, 2] <= width - 0.5 + eps)
        & (boxes[:, 3] <= height - 0.5 + eps)
        & (boxes[:, 2] > boxes[:, 0])
        & (boxes[:, 3] > boxes[:, 1])
    )
    if not inside.all():
        bad = int(np.flatnonzero(~inside)[0])
        raise InputError(
            f"{path}: box {bad} {boxes[bad].tolist()} is empty or outside the {height}x{width} image "
            "(README pixel coordinates span [-0.5, W - 0.5])"
        )
    scores = arrays.get("scores")
    if scores is not None and not np.isfinite(scores).all():
        raise InputError(f"{path}: scores has non-finite values")
    if "masks" in arrays:
        return PrecomputedProposals(
            boxes,
            image_size,
            None if scores is None else scores.astype(np.float32),
            packed_masks=arrays["masks"],
        )
    indptr = arrays["indptr"].astype(np.int64)
    indices = arrays["indices"]
    if indptr[0] != 0 or indptr[-1] != len(indices) or (np.diff(indptr) < 0).any():
        raise InputError(
            f"{path}: indptr must start at 0, not decrease, and end at len(indices) = {len(indices)}"
        )
    count = int(arrays["superpixels"].max(initial=0)) + 1
    if len(indices) and (indices.min() < 0 or indices.max() >= count):
        raise InputError(f"{path}: indices must be superpixel ids in [0, {count})")
    return PrecomputedProposals(
        boxes,
        image_size,
        None if scores is None else scores.astype(np.float32),
        superpixels=arrays["superpixels"].astype(np.int32),
        indptr=indptr,
        indices=indices.astype(np.int32),
    )
