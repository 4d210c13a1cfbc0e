"""Reader of the authors' NYUv2 release (``NYUV2_3D_dataset.zip`` of github phoenixnn/Amodal3Det).

Layout of the unzipped release folder ``ROOT`` (``dataset/NYUV2`` in the authors' tree), as their
``matlab/NYUV2/*.m`` and ``rgbd_3det/data/setup_*_data.py`` read it; ``i`` is the image number,
1..1449, all images in the NYUv2 standard crop (427 x 561):

* ``annotations/{i}.mat``: variable ``data``, a struct with (among others)
  ``Rtilt`` (3, 3), ``p_tilt = Rtilt p_cam``;
  ``gt3D`` cell (1, M), each 8 x 3 box corners in the tilt frame, metres (an empty cell: the
  object has no 3D box); ``gtLabelNames`` cell (1, M) of class names; ``gt2Dsel`` cell (1, M),
  each ``[xmin ymin xmax ymax]``, 1-based inclusive pixel indices (the authors' ``extract_GTInfo.m``
  subtracts 1 to get 0-based Fast R-CNN boxes). The struct also holds ``img``, ``rawDepth`` and
  ``K``; only ``rawDepth`` is used, and only when the ``rawDepth`` folder is absent.
* ``color/{i}.jpg``: colour.
* ``rawDepth/{i}.mat``: variable ``rawDepth`` (H, W), metres, 0 = missing.
* ``dmap_f/{i}.mat``: variable ``dmap_f`` (H, W), the hole-filled depth, metres (the authors
  clip it at 10 m and scale it to 0..255 for the depth trunk).
* ``trainval.txt`` (795 images) and ``test.txt`` (654): one image number per line.

Field mapping to a3d (``read_image``):

* objects kept: as ``extract_GTInfo.m``, those whose class is one of the 19 and that have a 3D
  box; class names are normalised first (``normalize_class_name``);
* ``box3d`` = ``geometry.boxes_from_corners_tilt(gt3D, Rtilt)`` (the release's
  ``VectorizeBboxes.m``: camera-frame centre, l >= w, theta in radians where the script gives
  degrees);
* ``box2d_visible`` = ``gt2Dsel`` in README pixel coordinates:
  ``[xmin - 1.5, ymin - 1.5, xmax - 0.5, ymax - 0.5]`` (1-based inclusive indices -> pixel edges);
* ``box2d_amodal`` = the 3D box projected with ``NYU_CROP_INTRINSICS`` and clipped to the image;
* intrinsics: ``geometry.NYU_CROP_INTRINSICS`` (docs/conventions.md; the struct's ``K`` is not read).

MATLAB files are read with ``scipy.io.loadmat``, or with ``h5py`` for MATLAB v7.3 (HDF5) files;
``load_mat`` turns both into the same plain Python values (structs -> dict, cells -> list,
char -> str, numeric -> ndarray of the MATLAB shape).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.sources.folder import NPY_MILLIMETRE_MEDIAN, read_color_bytes
from a3d.runtime.structures.boxes import SIZE
from a3d.runtime.structures.classes import normalize_class_name
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import (
    NYU_CROP_INTRINSICS,
    Intrinsics,
    boxes_from_corners_tilt,
    boxes_from_pixel_bounds,
    check_rotation,
    project_boxes_to_2d,
)

SPLIT_FILES = {"train": "trainval.txt", "test": "test.txt"}
SPLIT_SIZES = {"train": 795, "test": 654}
"""The standard NYUv2 split (docs/conventions.md "Evaluation")."""
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


@dataclass(frozen=True)
class NyuImage:
    """One image of the release, converted to a3d conventions (see the module docstring)."""

    index: int
    color: bytes  # the release's JPEG, checked, not decoded
    image_size: tuple[int, int]  # (H, W)
    depth_raw: np.ndarray  # (H, W) float32 metres, 0 = missing
    depth_filled: np.ndarray  # (H, W) float32 metres, the release's hole-filled depth
    R_tilt: np.ndarray  # (3, 3)
    intrinsics: Intrinsics
    gt: GroundTruth


def matlab_boxes_to_pixels(boxes: np.ndarray) -> np.ndarray:
    """``[xmin ymin xmax ymax]`` 1-based inclusive pixel indices -> README ``[x1, y1, x2, y2]``."""
    return boxes_from_pixel_bounds(np.asarray(boxes, dtype=np.float64) - 1.0)


def read_split(root: str | Path, split: str) -> list[int]:
    """Image numbers of ``split`` ("train" = trainval.txt, "test" = test.txt), in file order."""
    path = Path(root) / SPLIT_FILES[split]
    try:
        lines = path.read_text().splitlines()
    except OSError as error:
        raise InputError(f"{path}: cannot read the split file: {error.strerror or error}") from None
    indices: list[int] = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        if not line.strip().isdigit() or int(line) < 1:
            raise InputError(f"{path}: line {number}: expected an image number, got {line.strip()!r}")
        indices.append(int(line))
    if len(set(indices)) != len(indices):
        raise InputError(f"{path}: lists an image more than once")
    return indices


def read_image(root: str | Path, index: int) -> NyuImage:
    """Read image ``index`` of the release at ``root`` (colour, depths, R_tilt, ground truth)."""
    root = Path(root)
    annotation_path = root / "annotations" / f"{index}.mat"
    data = load_mat(annotation_path).get("data")
    if not isinstance(data, dict):
        raise InputError(f"{annotation_path}: no struct 'data'")
    color, header = read_color_bytes(root / "color" / f"{index}.jpg")
    raw_path = root / "rawDepth" / f"{index}.mat"
    if raw_path.exists():
        depth_raw = _depth(load_mat(raw_path).get("rawDepth"), raw_path, "rawDepth", header.size)
    else:
        depth_raw = _depth(data.get("rawDepth"), annotation_path, "data.rawDepth", header.size)
    filled_path = root / "dmap_f" / f"{index}.mat"
    depth_filled = _depth(load_mat(filled_path).get("dmap_f"), filled_path, "dmap_f", header.size)
    R_tilt, gt = read_annotation(annotation_path, data, header.size)
    return NyuImage(index, color, header.size, depth_raw, depth_filled, R_tilt, NYU_CROP_INTRINSICS, gt)


def read_annotation(
    path: Path, data: dict[str, Any], image_size: tuple[int, int], K: Intrinsics = NYU_CROP_INTRINSICS
) -> tuple[np.ndarray, GroundTruth]:
    """R_tilt and ground truth from an annotation's ``data`` struct (loaded from ``path``)."""
    for field in ("Rtilt", "gt3D", "gtLabelNames", "gt2Dsel"):
        if field not in data:
            raise InputError(f"{path}: data has no field {field!r}")
    if not isinstance(data["Rtilt"], np.ndarray) or data["Rtilt"].dtype.kind not in "fiu":
        raise InputError(f"{path}: data.Rtilt must be a numeric 3x3 matrix")
    R_tilt = check_rotation(data["Rtilt"], f"{path}: data.Rtilt")
    corners3d, names, sel = (_cell(data[f], path, f) for f in ("gt3D", "gtLabelNames", "gt2Dsel"))
    if not len(corners3d) == len(names) == len(sel):
        raise InputError(
            f"{path}: gt3D, gtLabelNames and gt2Dsel have {len(corners3d)}, {len(names)}, {len(sel)} entries"
        )
    classes, corners, boxes2d = [], [], []
    for j, (c, name, box) in enumerate(zip(corners3d, names, sel, strict=True)):
        cls = normalize_class_name(name) if isinstance(name, str) else None
        if cls is None or np.size(c) == 0:
            continue
        c = np.asarray(c, dtype=np.float64)
        box = np.asarray(box, dtype=np.float64).reshape(-1)
        if c.shape != (8, 3) or not np.isfinite(c).all():
            raise InputError(f"{path}: gt3D{{{j + 1}}} must be 8x3 finite corners, got shape {c.shape}")
        if box.shape != (4,) or not np.isfinite(box).all() or box[2] < box[0] or box[3] < box[1]:
            raise InputError(f"{path}: gt2Dsel{{{j + 1}}} must be [xmin ymin xmax ymax], got {box.tolist()}")
        classes.append(cls)
        corners.append(c)
        boxes2d.append(box)
    boxes3d = boxes_from_corners_tilt(np.reshape(corners, (-1, 8, 3)), R_tilt)
    flat = np.flatnonzero(~(boxes3d[:, SIZE] > 0).all(axis=1))
    if flat.size:
        raise InputError(f"{path}: the 3D box of object {classes[flat[0]]!r} is flat (a zero size)")
    amodal = project_boxes_to_2d(boxes3d, R_tilt, K, image_size)
    visible = matlab_boxes_to_pixels(np.reshape(boxes2d, (-1, 4)))
    return R_tilt, GroundTruth.from_classes(classes, boxes3d, visible, amodal)


def _cell(value: Any, path: Path, field: str) -> list[Any]:
    if isinstance(value, np.ndarray) and value.size == 0:
        return []  # an empty matrix where a 0-element cell was meant
    if not isinstance(value, list):
        raise InputError(f"{path}: data.{field} must be a cell array, got {type(value).__name__}")
    return value


def _depth(value: Any, path: Path, name: str, size: tuple[int, int]) -> np.ndarray:
    """A depth matrix in metres, checked: 2D of the colour's size, finite, >= 0, not millimetres."""
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiu":
        raise InputError(f"{path}: no numeric matrix {name!r}")
    if value.shape != size:
        raise InputError(
            f"{path}: {name} is {'x'.join(map(str, value.shape))} but colour is {size[0]}x{size[1]}"
        )
    depth = value.astype(np.float32)
    if not np.isfinite(depth).all() or (depth < 0).any():
        raise InputError(f"{path}: {name} has NaN, inf or negative values")
    valid = depth[depth > 0]
    if valid.size and np.median(valid) > NPY_MILLIMETRE_MEDIAN:
        raise InputError(
            f"{path}: {name} looks like millimetres (median {np.median(valid):g}); expected metres"
        )
    return depth


# ----------------------------------------------------------------------------- MATLAB files


def load_mat(path: str | Path) -> dict[str, Any]:
    """Variables of a MATLAB ``.mat`` file (v5/v7 via scipy, v7.3/HDF5 via h5py) as plain Python.

    Structs become dicts, cell arrays lists (MATLAB's column-major order), char arrays str and
    numeric arrays ndarrays of the MATLAB shape. Unreadable files are an InputError.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(520)
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror or error}") from None
    if not head:
        raise InputError(f"{path}: file is empty (0 bytes)")
    if _HDF5_SIGNATURE in (head[:8], head[512:520]):
        return _load_mat_hdf5(path)
    import scipy.io  # the 'train' extra; imported here so that a3d-nyuv2 --help needs no scipy

    try:
        raw = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=True, chars_as_strings=True)
    except (
        ValueError,
        TypeError,
        OSError,
        EOFError,
        NotImplementedError,
        scipy.io.matlab.MatReadError,
    ) as error:
        raise InputError(f"{path}: cannot read the MATLAB file ({error})") from None
    return {key: _from_scipy(value) for key, value in raw.items() if not key.startswith("__")}


def _from_scipy(value: Any) -> Any:
    if not isinstance(value, np.ndarray):
        return value
    if value.dtype.names:  # struct (array)
        records = [{name: _from_scipy(r[name]) for name in value.dtype.names} for r in value.ravel(order="F")]
        return records[0] if len(records) == 1 else records
    if value.dtype.kind == "U":
        return "".join(value.ravel(order="F").tolist())
    if value.dtype == object:  # cell
        return [_from_scipy(item) for item in value.ravel(order="F")]
    return value


def _load_mat_hdf5(path: Path) -> dict[str, Any]:
    try:
        import h5py  # only MATLAB v7.3 files need it
    except ImportError:
        raise InputError(
            f"{path}: is a MATLAB v7.3 (HDF5) file; reading it needs h5py (pip install 'a3d[train]')"
        ) from None

    def convert(node: Any, f: h5py.File) -> Any:
        """One MATLAB variable; HDF5 holds MATLAB arrays transposed (MATLAB is column-major)."""
        if isinstance(node, h5py.Group):
            return {key: convert(node[key], f) for key in node}
        kind = node.attrs.get("MATLAB_class", b"")
        kind = kind.decode() if isinstance(kind, bytes) else str(kind)
        if node.attrs.get("MATLAB_empty", 0):
            return {"cell": [], "char": ""}.get(kind, np.zeros((0, 0)))
        array = node[()]
        if kind == "cell":
            return [convert(f[ref], f) for ref in array.ravel()]
        if kind == "char":
            return "".join(map(chr, array.ravel()))
        return np.asarray(array).T

    try:
        with h5py.File(path, "r") as f:
            return {key: convert(f[key], f) for key in f if not key.startswith("#")}
    except (OSError, KeyError, ValueError) as error:
        raise InputError(f"{path}: cannot read the MATLAB v7.3 file ({error})") from None
