"""TUM RGB-D benchmark sequences (Sturm et al., IROS 2012) as a frame source.

A sequence folder (``rgbd_dataset_freiburg1_desk``, ...) holds ``rgb.txt`` and ``depth.txt``:
one ``timestamp path`` line per image (seconds; the path relative to the folder; lines starting
with ``#`` are comments), ``rgb/*.png`` 8-bit colour and ``depth/*.png`` 16-bit depth, 5000 units
per metre (``TUM_DEPTH_SCALE``), 0 = missing, registered to the colour camera.

Colour and depth are captured at slightly different times, so they are paired as the benchmark's
own ``associate.py`` pairs them: every (colour, depth) pair less than ``max_difference`` seconds
apart (default 0.02 s) is a candidate, candidates are taken from the closest up, and each stamp is
used at most once. Colour images left without depth are not frames; their number (and the depth
images left over) is one warning line when the run starts. A frame is named by its colour
timestamp as ``rgb.txt`` writes it, and carries it in ``Frame.timestamp``; frames come in colour
time order.

Intrinsics: ``--intrinsics fx,fy,cx,cy`` or a preset name (fr1, fr2, fr3: the benchmark's
published calibrations); without it the folder's name ``rgbd_dataset_freiburgN_*`` selects
preset ``frN``, and any other name is an error that asks for ``--intrinsics``. The images are
not undistorted (the benchmark's fr1/fr2 colour images carry a small radial distortion).

Poses: where the folder has ``groundtruth.txt`` (the motion-capture trajectory), each frame gets
the camera-to-world pose at its colour time (a3d.runtime.sources.trajectory: interpolated, none
outside the trajectory or across a gap of more than ``max_gap`` seconds, a note saying why). The
mocap world is not gravity-aligned (docs/sources.md "Camera poses"), so gravity is still estimated
from each frame's depth.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.image_io import read_uint16_png
from a3d.runtime.sources.arrays import frame_from_arrays
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.folder import read_color
from a3d.runtime.sources.overrides import INTRINSICS_PRESETS, fit_depth
from a3d.runtime.sources.trajectory import (
    DEFAULT_MAX_GAP,
    TRAJECTORY_FILE,
    Trajectory,
    frame_pose,
    read_trajectory,
)
from a3d.runtime.sources.wording import option
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics

logger = logging.getLogger(__name__)

TUM_DEPTH_SCALE = 1.0 / 5000.0  # metres per depth unit
DEFAULT_MAX_DIFFERENCE = 0.02  # seconds between a paired colour and depth image
LIST_FILES = ("rgb.txt", "depth.txt")
_SEQUENCE_NAME = re.compile(r"rgbd_dataset_freiburg([123])_")


@dataclass(frozen=True)
class Stamped:
    """One line of rgb.txt / depth.txt: its time stamp (as written and in seconds) and image file."""

    text: str
    seconds: float
    path: Path


def is_tum_sequence(spec: str) -> bool:
    path = Path(spec)
    return path.is_dir() and all((path / name).is_file() for name in LIST_FILES)


def read_list(path: Path, problems: list[str]) -> list[Stamped]:
    """The images of an rgb.txt / depth.txt, in file order; a malformed line goes to ``problems``."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    entries = []
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        try:
            seconds = float(fields[0]) if len(fields) == 2 else float("nan")
        except ValueError:
            seconds = float("nan")
        if not np.isfinite(seconds):
            problems.append(f"{path}:{number}: expected 'timestamp path', got {line.strip()[:60]!r}")
            continue
        entries.append(Stamped(fields[0], seconds, path.parent / fields[1]))
    return entries


def associate(colour: list[float], depth: list[float], max_difference: float) -> list[tuple[int, int]]:
    """(colour index, depth index) pairs, as the benchmark's associate.py makes them (module
    docstring), sorted by colour index."""
    c, d = np.asarray(colour, np.float64), np.asarray(depth, np.float64)
    order = np.argsort(d, kind="stable")
    lo = np.searchsorted(d[order], c - max_difference, side="right")
    hi = np.searchsorted(d[order], c + max_difference, side="left")
    candidates = [
        (abs(c[i] - d[order[k]]), i, int(order[k])) for i in range(len(c)) for k in range(lo[i], hi[i])
    ]
    used_c: set[int] = set()
    used_d: set[int] = set()
    pairs = []
    for _, i, j in sorted(candidates):
        if i not in used_c and j not in used_d:
            used_c.add(i)
            used_d.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def sequence_intrinsics(folder: Path, given: Intrinsics | None) -> Intrinsics:
    """The given intrinsics, else the freiburg preset the folder's name names (InputError if none)."""
    if given is not None:
        return given
    match = _SEQUENCE_NAME.match(folder.resolve().name)
    if match is None:
        raise InputError(
            f"{folder}: not named rgbd_dataset_freiburgN_*, so its camera is unknown; "
            f"pass {option('intrinsics_or_preset')}"
        )
    return INTRINSICS_PRESETS[f"fr{match.group(1)}"]


class TumSource:
    """A TUM RGB-D sequence folder as a frame source (module docstring)."""

    depth_scale = TUM_DEPTH_SCALE

    def __init__(
        self,
        folder: str | os.PathLike,
        intrinsics: Intrinsics | None = None,
        max_difference: float = DEFAULT_MAX_DIFFERENCE,
        resize_depth: bool = False,
        max_gap: float = DEFAULT_MAX_GAP,
    ) -> None:
        self.folder = Path(folder)
        self.intrinsics = sequence_intrinsics(self.folder, intrinsics)
        self.resize_depth = resize_depth
        self.incomplete: list[str] = []
        colour = read_list(self.folder / "rgb.txt", self.incomplete)
        depth = read_list(self.folder / "depth.txt", self.incomplete)
        pairs = associate([e.seconds for e in colour], [e.seconds for e in depth], max_difference)
        self.pairs = [(colour[i], depth[j]) for i, j in pairs]
        self.unpaired = (len(colour) - len(pairs), len(depth) - len(pairs))
        self.max_difference = max_difference
        self.max_gap = max_gap
        trajectory_file = self.folder / TRAJECTORY_FILE
        self.trajectory: Trajectory | None = (
            read_trajectory(trajectory_file, self.incomplete) if trajectory_file.is_file() else None
        )

    @property
    def has_poses(self) -> bool:
        """Whether the sequence has a trajectory (frames outside it still go without a pose)."""
        return self.trajectory is not None

    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self) -> Iterator[FrameLoader]:
        colour_left, depth_left = self.unpaired
        if colour_left or depth_left:
            logger.warning(
                "%s: %d colour image(s) without depth within %g s skipped (%d depth image(s) unused)",
                self.folder,
                colour_left,
                self.max_difference,
                depth_left,
            )
        for colour, depth in self.pairs:
            files = (str(colour.path), str(depth.path))
            yield FrameLoader(colour.text, str(colour.path), lambda c=colour, d=depth: self.read(c, d), files)

    def read(self, colour: Stamped, depth: Stamped) -> Frame:
        bgr = read_color(colour.path)
        units = fit_depth(read_uint16_png(depth.path), bgr.shape[:2], self.resize_depth, depth.path)
        frame = frame_from_arrays(
            bgr[..., ::-1],
            units,
            self.intrinsics,
            depth_scale=TUM_DEPTH_SCALE,
            name=colour.text,
            origin=str(colour.path),
            timestamp=colour.seconds,
        )
        pose, note = self.pose(colour)
        files = {"color_file": str(colour.path), "depth_file": str(depth.path)}
        return replace(frame, **files, pose=pose, pose_note=note)

    def pose(self, colour: Stamped) -> tuple[np.ndarray | None, str]:
        """The frame's pose at its colour time and "", or None and the note that says why it has
        none (also a warning); (None, "") for a sequence without a trajectory."""
        return frame_pose(self.trajectory, colour.seconds, self.max_gap, colour.path)
