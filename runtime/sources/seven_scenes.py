"""Posed RGB-D folders in the layout of Microsoft's 7-Scenes (Shotton et al., CVPR 2013).

A sequence folder holds, per frame ``frame-NNNNNN``:

* ``frame-NNNNNN.color.png`` (or ``.jpg``): 8-bit colour;
* ``frame-NNNNNN.depth.png``: uint16 millimetres, 0 = missing; 7-Scenes writes 65535 where the
  Kinect saw nothing, which is read as missing too (``NO_DEPTH``);
* ``frame-NNNNNN.pose.txt``: the 4 x 4 camera-to-world pose, four lines of four numbers;

and once, ``camera-intrinsics.txt``: the 3 x 3 camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``
(``--intrinsics`` replaces it, and then the file may be absent or unreadable).

Depth is taken as registered to the colour image (the same size is required; ``--resize-depth``
as for every source). The files are read as the a3d frame folder's are (a3d.runtime.sources.folder),
with the same checks. A frame whose pose file is missing, unreadable or holds no rigid transform
is read without a pose: its line notes why and a warning names the file. The world of 7-Scenes'
poses (that of its KinectFusion reconstruction) is not gravity-aligned, so gravity is estimated
from each frame's depth (docs/sources.md "Camera poses").
"""

from __future__ import annotations

import logging
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.sources.arrays import intrinsics_from
from a3d.runtime.sources.folder import FolderSource, FrameRef
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics
from a3d.runtime.structures.pose import check_pose

logger = logging.getLogger(__name__)

INTRINSICS_FILE = "camera-intrinsics.txt"
POSE_SUFFIX = ".pose.txt"
FRAME_PREFIX = "frame-"
NO_DEPTH = 65535  # 7-Scenes' "no measurement" in its depth PNGs
_NO_DEPTH_M = np.float32(NO_DEPTH) / np.float32(1000)  # what the folder reader makes of it


def is_seven_scenes(spec: str) -> bool:
    """A folder with ``camera-intrinsics.txt`` and ``frame-*.color.*`` files."""
    path = Path(spec)
    if not (path.is_dir() and (path / INTRINSICS_FILE).is_file()):
        return False
    return any(name.startswith(FRAME_PREFIX) and ".color." in name for name in os.listdir(path))


def read_intrinsics_matrix(path: Path) -> Intrinsics:
    """``camera-intrinsics.txt``: a 3 x 3 camera matrix, three lines of three numbers."""
    K = read_matrix(path, 3, "a 3x3 camera matrix (9 numbers)")
    try:
        return intrinsics_from(K)
    except InputError as e:
        raise InputError(f"{path}: {str(e).removeprefix('intrinsics: ')}") from None


def read_pose_file(path: Path) -> np.ndarray:
    """A 4 x 4 pose text file, checked rigid (InputError "PATH: ..." otherwise)."""
    return check_pose(read_matrix(path, 4, "a 4x4 pose (16 numbers)"), str(path))


def read_matrix(path: Path, n: int, expected: str) -> np.ndarray:
    """The n x n matrix of a text file of n * n whitespace-separated numbers (InputError "PATH:
    missing", "cannot read" or "expected EXPECTED, got ...")."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: missing") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        values = []
    if len(values) != n * n:
        raise InputError(f"{path}: expected {expected}, got {text.strip()[:60]!r}")
    return np.array(values).reshape(n, n)


class SevenScenesSource(FolderSource):
    """A 7-Scenes-style sequence folder as a frame source (module docstring)."""

    has_poses = True

    def __init__(self, folder: str | os.PathLike, intrinsics: Intrinsics | None = None) -> None:
        super().__init__(folder, with_proposals=False, with_truth=False)
        self.intrinsics = intrinsics or read_intrinsics_matrix(self.folder / INTRINSICS_FILE)

    def read(self, ref: FrameRef) -> Frame:
        frame = super().read(ref)
        depth = np.where(frame.depth == _NO_DEPTH_M, np.float32(0), frame.depth)
        try:
            return replace(frame, depth=depth, pose=read_pose_file(self.folder / f"{ref.name}{POSE_SUFFIX}"))
        except InputError as e:
            logger.warning("%s (the frame is processed without a pose)", e)
            return replace(frame, depth=depth, pose_note=f"no pose: {e}")
