"""SUN RGB-D (Song, Lichtenberg & Xiao, CVPR 2015) as a frame source, in its two common layouts.

**The release** (``SUNRGBD.zip``): one folder per frame, nested by sensor and sub-set
(``SUNRGBD/kv1/NYUdata/NYU0001/``), each holding ``image/*.jpg``, ``depth/*.png`` (raw) and
``depth_bfx/*.png`` (hole-filled; ``depth="filled"``), ``intrinsics.txt`` (3 x 3, row by row),
``extrinsics/*.txt`` (the tilt; the last file by name, as the toolbox reads it) and
``annotation3Dfinal/index.json`` (objects with a footprint polygon and a vertical extent). SOURCE
is one such folder or any folder above them; other folders (``fullres/``, ``annotation2Dfinal/``,
``status/``, ...) are ignored. A frame is named by its folder's path below SOURCE, the parts
joined by ``__`` (``kv1__NYUdata__NYU0001``), or by the folder's own name when SOURCE is it. No
extrinsics: R_tilt is left to the pipeline's gravity estimate (and the frame has no ground truth).
The release has no per-object 2D box for its 3D annotation; as the toolbox's ``readframeSUNRGBD``,
both 2D boxes are the projection of the 3D box, clipped to the image.

**The VoteNet / mmdetection3d layout** (what their ``extract_rgbd_data_v2.m`` writes,
``sunrgbd_trainval/``): ``image/%06d.jpg``, ``depth/%06d.mat`` (variable ``instance``, the
frame's point cloud N x 6, x y z r g b in SUN's upright frame), ``calib/%06d.txt`` (``Rtilt`` then
``K``, each 9 numbers column by column), ``label/%06d.txt`` (``class x y w h cx cy cz hx hy hz ox
oy`` per object), and ``train_data_idx.txt`` / ``val_data_idx.txt``. The cloud is projected back
through K and R_tilt into a depth map: each point to its nearest pixel, the nearest surface
winning, pixels without a point missing (a subsampled cloud gives sparse depth). Reading the
``.mat`` needs scipy (the ``sunrgbd`` extra). Frames are named ``%06d``; the label's 2D box is the
visible box, the projected 3D box the amodal one.

Conventions (axes, tilt, pixels, depth values, boxes, classes):
``a3d.runtime.sources.sunrgbd_conventions``. Ground truth uses ``classes`` "nyu19" (default) or
"sun10"; objects of other names are dropped.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.image_io import read_uint16_png
from a3d.runtime.sources.arrays import MILLIMETRE, frame_from_arrays
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.folder import read_color
from a3d.runtime.sources.overrides import fit_depth
from a3d.runtime.sources.sunrgbd_conventions import (
    CLASS_SETS,
    annotation_from_upright,
    boxes2d_from_sun,
    boxes_from_footprints,
    boxes_from_labels,
    decode_depth_png,
    depth_from_points,
    intrinsics_from_sun,
    map_class,
    nearest_rotation,
    rtilt_from_annotation,
)
from a3d.runtime.structures.frame import Frame, GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, project_boxes_to_2d

DEPTH_FOLDERS = {"raw": "depth", "filled": "depth_bfx"}
VOTENET_FOLDERS = ("image", "depth", "calib")
VOTENET_SPLITS = {"train": "train_data_idx.txt", "val": "val_data_idx.txt"}
NAME_SEPARATOR = "__"


@dataclass(frozen=True)
class SunOptions:
    """``depth``: "raw" or "filled" (release layout); ``classes``: "nyu19" or "sun10";
    ``with_truth``: read the annotation; ``resize_depth``: see sources.overrides.fit_depth."""

    depth: str = "raw"
    classes: str = "nyu19"
    with_truth: bool = True
    resize_depth: bool = False

    def __post_init__(self) -> None:
        if self.depth not in DEPTH_FOLDERS:
            raise InputError(f"depth: expected one of {', '.join(DEPTH_FOLDERS)}, got {self.depth!r}")
        if self.classes not in CLASS_SETS:
            raise InputError(f"classes: expected one of {', '.join(CLASS_SETS)}, got {self.classes!r}")


# ----------------------------------------------------------------------------- recognising


def is_release_frame(path: Path) -> bool:
    """A release frame folder: intrinsics.txt and an image/ folder."""
    return (path / "intrinsics.txt").is_file() and (path / "image").is_dir()


def is_votenet_root(path: Path) -> bool:
    return all((path / name).is_dir() for name in VOTENET_FOLDERS)


def find_release_frames(root: Path) -> Iterator[Path]:
    """Release frame folders at or below ``root``, sorted (a frame folder is not searched further)."""
    if is_release_frame(root):
        yield root
        return
    try:
        children = sorted(entry.path for entry in os.scandir(root) if entry.is_dir())
    except OSError:
        return
    for child in children:
        yield from find_release_frames(Path(child))


def is_sunrgbd(spec: str) -> bool:
    path = Path(spec)
    return path.is_dir() and (is_votenet_root(path) or next(find_release_frames(path), None) is not None)


def open_sunrgbd(
    spec: str | os.PathLike, options: SunOptions = SunOptions()
) -> ReleaseSource | VotenetSource:
    """The SUN RGB-D source at ``spec``, in whichever layout it has (InputError if neither)."""
    path = Path(spec)
    if not path.is_dir():
        raise InputError(f"{path}: {'not a folder' if path.exists() else 'no such folder'}")
    if is_votenet_root(path):
        return VotenetSource(path, options)
    source = ReleaseSource(path, options)
    if not source.folders:
        raise InputError(
            f"{path}: no SUN RGB-D frame folder (intrinsics.txt + image/) and no calib/ + depth/ + image/"
        )
    return source


# ----------------------------------------------------------------------------- small files


def read_numbers(path: Path, count: int | None = None) -> np.ndarray:
    """All numbers of a whitespace- or comma-separated text file (InputError naming the file)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        numbers = np.array([float(v) for v in text.replace(",", " ").split()], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: expected numbers only") from None
    if count is not None and numbers.size != count:
        raise InputError(f"{path}: expected {count} numbers, found {numbers.size}")
    if not np.isfinite(numbers).all():
        raise InputError(f"{path}: has NaN or infinite numbers")
    return numbers


def _only_file(folder: Path, suffix: str) -> Path:
    files = sorted(p for p in folder.glob(f"*{suffix}") if p.is_file()) if folder.is_dir() else []
    if not files:
        raise InputError(f"{folder}: no *{suffix} file")
    return files[0]


def _frame(
    color: np.ndarray,
    depth: np.ndarray,
    K: Intrinsics,
    R_tilt: np.ndarray | None,
    name: str,
    files: tuple[Path, Path],
) -> Frame:
    frame = frame_from_arrays(color[..., ::-1], depth, K, R_tilt, name=name, origin=str(files[0]))
    return replace(frame, color_file=str(files[0]), depth_file=str(files[1]))


def _truth(
    classes: list[str], boxes3d: np.ndarray, visible: np.ndarray | None, R_tilt, K, size
) -> GroundTruth:
    boxes3d = np.asarray(boxes3d, dtype=np.float64).reshape(-1, 7)
    amodal = project_boxes_to_2d(boxes3d, R_tilt, K, size) if len(boxes3d) else np.zeros((0, 4))
    return GroundTruth.from_classes(classes, boxes3d, amodal if visible is None else visible, amodal)


# ----------------------------------------------------------------------------- the release


class ReleaseSource:
    """The release's frame folders at or below ``root`` (module docstring)."""

    depth_scale = MILLIMETRE

    def __init__(self, root: Path, options: SunOptions) -> None:
        self.root = root
        self.options = options
        self.folders = list(find_release_frames(root))
        self.incomplete: list[str] = []

    def __len__(self) -> int:
        return len(self.folders)

    def name_of(self, folder: Path) -> str:
        parts = folder.relative_to(self.root).parts
        return NAME_SEPARATOR.join(parts) if parts else folder.name

    def __iter__(self) -> Iterator[FrameLoader]:
        for folder in self.folders:
            files = (
                str(p)
                for sub in ("image", "depth", "depth_bfx", "extrinsics", "annotation3Dfinal")
                for p in sorted((folder / sub).glob("*.*"))
            )
            named = (str(folder / "intrinsics.txt"), *files)
            yield FrameLoader(self.name_of(folder), str(folder), lambda f=folder: self.read(f), named)

    def read(self, folder: Path) -> Frame:
        color_path = _only_file(folder / "image", ".jpg")
        depth_path = _only_file(folder / DEPTH_FOLDERS[self.options.depth], ".png")
        K = intrinsics_from_sun(read_numbers(folder / "intrinsics.txt", 9).reshape(3, 3))
        bgr = read_color(color_path)
        depth = fit_depth(
            decode_depth_png(read_uint16_png(depth_path)),
            bgr.shape[:2],
            self.options.resize_depth,
            depth_path,
        )
        E = self.extrinsics(folder)
        R_tilt = None if E is None else rtilt_from_annotation(E)
        frame = _frame(bgr, depth, K, R_tilt, self.name_of(folder), (color_path, depth_path))
        index = folder / "annotation3Dfinal" / "index.json"
        if not self.options.with_truth or E is None or not index.is_file():
            return frame
        classes, footprints, heights = read_annotation(index, self.options.classes)
        boxes = boxes_from_footprints(footprints, heights, E, R_tilt) if classes else np.zeros((0, 7))
        return replace(frame, truth=_truth(classes, boxes, None, R_tilt, K, bgr.shape[:2]))

    @staticmethod
    def extrinsics(folder: Path) -> np.ndarray | None:
        """E (``w = E c``) from the last extrinsics/*.txt by name, or None when there is none."""
        files = sorted((folder / "extrinsics").glob("*.txt")) if (folder / "extrinsics").is_dir() else []
        if not files:
            return None
        numbers = read_numbers(files[-1])
        if numbers.size not in (9, 12):
            raise InputError(f"{files[-1]}: expected a 3x3 or 3x4 matrix, found {numbers.size} numbers")
        return nearest_rotation(numbers.reshape(3, -1)[:, :3], str(files[-1]))

    def splits(self, split_file: Path | None = None) -> dict[str, str] | None:
        """Frame name -> "train" / "val" from the toolbox's allsplit.mat (``alltrain`` /
        ``alltest``, as VoteNet splits): ``split_file``, else ``find_split_file``; None without one."""
        path = split_file or find_split_file(self.root)
        if path is None:
            return None
        keys = read_allsplit(path)
        out: dict[str, str] = {}
        for folder in self.folders:
            parts = folder.resolve().parts
            for k in range(1, len(parts) + 1):
                split = keys.get("/".join(parts[-k:]))
                if split is not None:
                    out[self.name_of(folder)] = split
                    break
        return out


SPLIT_FILE = Path("SUNRGBDtoolbox") / "traintestSUNRGBD" / "allsplit.mat"


def find_split_file(root: Path) -> Path | None:
    """``SUNRGBDtoolbox/traintestSUNRGBD/allsplit.mat`` in ``root`` or a folder above it, if any."""
    for folder in (root.resolve(), *root.resolve().parents):
        if (folder / SPLIT_FILE).is_file():
            return folder / SPLIT_FILE
    return None


def read_allsplit(path: Path) -> dict[str, str]:
    """allsplit.mat's frame folders ("kv1/NYUdata/NYU0001", the part after ``SUNRGBD/``) -> split."""
    loadmat = _loadmat(path)
    try:
        document = loadmat(path, variable_names=["alltrain", "alltest"])
    except (OSError, ValueError, TypeError, NotImplementedError) as e:
        raise InputError(f"{path}: cannot read the MATLAB file ({e})") from None
    out: dict[str, str] = {}
    for variable, split in (("alltrain", "train"), ("alltest", "val")):
        cells = document.get(variable)
        if not isinstance(cells, np.ndarray) or cells.dtype != object:
            raise InputError(f"{path}: expected a cell array of folder paths {variable!r}")
        for cell in cells.ravel():
            text = "".join(np.asarray(cell).ravel().tolist()).strip().rstrip("/")
            out[text.split("/SUNRGBD/")[-1].lstrip("/")] = split
    return out


def _loadmat(path: Path) -> Any:
    """scipy.io.loadmat, or InputError naming the extra that brings it."""
    try:
        import scipy.io
    except ImportError:
        raise InputError(
            f"{path}: reading SUN RGB-D .mat files needs scipy: pip install 'a3d[sunrgbd]'"
        ) from None
    return scipy.io.loadmat


def read_annotation(path: Path, classes: str) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(class names, footprints (N, 3, 2), heights (N, 2)) of an annotation3Dfinal/index.json,
    objects of a3d's classes only; empty entries (``null``, no polygon) are skipped as the toolbox does."""
    try:
        document = json.loads(path.read_bytes())
    except (OSError, ValueError) as e:
        raise InputError(
            f"{path}: cannot read the annotation ({getattr(e, 'strerror', None) or e})"
        ) from None
    objects = document.get("objects") if isinstance(document, dict) else None
    if not isinstance(objects, list):
        raise InputError(f'{path}: expected an object {{"objects": [...]}}')
    names, footprints, heights = [], [], []
    for k, obj in enumerate(objects):
        if not isinstance(obj, dict) or not obj.get("polygon") or not isinstance(obj.get("name"), str):
            continue
        cls = map_class(obj["name"], classes)
        if cls is None:
            continue
        polygon = obj["polygon"][0] if isinstance(obj["polygon"], list) else None
        try:
            X, Z = (np.asarray(polygon[key], dtype=np.float64).reshape(-1) for key in ("X", "Z"))  # type: ignore[index]
            ys = np.array([float(polygon["Ymin"]), float(polygon["Ymax"])])  # type: ignore[index]
        except (TypeError, KeyError, ValueError):
            raise InputError(f"{path}: objects[{k}].polygon[0] must hold X, Z, Ymin and Ymax") from None
        if (
            len(X) < 3
            or len(X) != len(Z)
            or not (np.isfinite(X).all() and np.isfinite(Z).all() and np.isfinite(ys).all())
        ):
            raise InputError(f"{path}: objects[{k}] footprint needs >= 3 finite (X, Z) points")
        names.append(cls)
        footprints.append(np.column_stack([X[:3], Z[:3]]))
        heights.append(ys)
    return names, np.asarray(footprints).reshape(-1, 3, 2), np.asarray(heights).reshape(-1, 2)


# ----------------------------------------------------------------------------- VoteNet / mmdetection3d


class VotenetSource:
    """The VoteNet / mmdetection3d ``sunrgbd_trainval`` folder (module docstring)."""

    depth_scale = None  # float metres from a point cloud: no unit for --depth-scale to replace

    def __init__(self, root: Path, options: SunOptions) -> None:
        self.root = root
        self.options = options
        self.incomplete: list[str] = []
        self.names: list[str] = []
        for image in sorted((root / "image").glob("*.jpg")):
            missing = [
                f"{d}/{image.stem}.{ext}"
                for d, ext in (("depth", "mat"), ("calib", "txt"))
                if not (root / d / f"{image.stem}.{ext}").is_file()
            ]
            if missing:
                self.incomplete.append(f"{image}: frame has no {' and no '.join(missing)}")
            else:
                self.names.append(image.stem)

    def __len__(self) -> int:
        return len(self.names)

    def __iter__(self) -> Iterator[FrameLoader]:
        for name in self.names:
            image = self.root / "image" / f"{name}.jpg"
            files = [
                self.root / sub / f"{name}.{ext}"
                for sub, ext in (("depth", "mat"), ("calib", "txt"), ("label", "txt"))
            ]
            named = (str(image), *map(str, files))
            yield FrameLoader(name, str(image), lambda n=name: self.read(n), named)

    def splits(self) -> dict[str, str] | None:
        """Frame name -> "train" / "val" from train_data_idx.txt / val_data_idx.txt, or None without them."""
        if not all((self.root / file).is_file() for file in VOTENET_SPLITS.values()):
            return None
        out: dict[str, str] = {}
        for split, file in VOTENET_SPLITS.items():
            for number in read_numbers(self.root / file):
                if number != int(number) or number < 0:
                    raise InputError(f"{self.root / file}: expected frame numbers, found {number:g}")
                out.setdefault(f"{int(number):06d}", split)
        return out

    def read(self, name: str) -> Frame:
        color_path = self.root / "image" / f"{name}.jpg"
        depth_path = self.root / "depth" / f"{name}.mat"
        calib = self.root / "calib" / f"{name}.txt"
        numbers = read_numbers(calib, 18)
        Rtilt_sun = nearest_rotation(numbers[:9].reshape(3, 3, order="F"), f"{calib}: Rtilt")
        K = intrinsics_from_sun(numbers[9:].reshape(3, 3, order="F"))
        E = annotation_from_upright(Rtilt_sun)
        R_tilt = rtilt_from_annotation(E)
        bgr = read_color(color_path)
        depth = depth_from_points(read_point_cloud(depth_path), Rtilt_sun, K, bgr.shape[:2])
        frame = _frame(bgr, depth, K, R_tilt, name, (color_path, depth_path))
        label = self.root / "label" / f"{name}.txt"
        if not self.options.with_truth or not label.is_file():
            return frame
        classes, boxes2d, rows = read_labels(label, self.options.classes)
        boxes = (
            boxes_from_labels(rows[:, :3], rows[:, 3:6], rows[:, 6:8], Rtilt_sun, R_tilt)
            if classes
            else np.zeros((0, 7))
        )
        return replace(frame, truth=_truth(classes, boxes, boxes2d, R_tilt, K, bgr.shape[:2]))


def read_labels(path: Path, classes: str) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(class names, a3d 2D boxes (N, 4), the 8 numbers cx cy cz hx hy hz ox oy (N, 8)) of a
    VoteNet label file, objects of a3d's classes only."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    names, boxes2d, rows = [], [], []
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if not fields:
            continue
        try:
            values = np.array([float(v) for v in fields[1:]], dtype=np.float64)
        except ValueError:
            values = np.zeros(0)
        if values.shape != (12,) or not np.isfinite(values).all():
            raise InputError(
                f"{path}:{number}: expected 'class x y w h cx cy cz hx hy hz ox oy', got {line[:60]!r}"
            )
        cls = map_class(fields[0], classes)
        if cls is not None:
            names.append(cls)
            boxes2d.append(values[:4])
            rows.append(values[4:])
    return names, boxes2d_from_sun(np.asarray(boxes2d).reshape(-1, 4)), np.asarray(rows).reshape(-1, 8)


def read_point_cloud(path: Path) -> np.ndarray:
    """The (N, >= 3) point cloud of a VoteNet ``depth/%06d.mat`` (variable ``instance``)."""
    loadmat = _loadmat(path)
    try:
        points: Any = loadmat(path, variable_names=["instance"]).get("instance")
    except (OSError, ValueError, TypeError, NotImplementedError) as e:
        raise InputError(f"{path}: cannot read the MATLAB file ({e})") from None
    if (
        not isinstance(points, np.ndarray)
        or points.ndim != 2
        or points.shape[1] < 3
        or points.dtype.kind not in "fiu"
    ):
        raise InputError(f"{path}: expected a numeric N x 6 matrix 'instance' (x y z r g b)")
    return points
