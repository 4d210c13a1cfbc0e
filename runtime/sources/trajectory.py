"""A camera trajectory in the TUM RGB-D format, and the pose it gives a frame taken at time t.

``groundtruth.txt`` (TUM RGB-D, Sturm et al. 2012) holds one ``timestamp tx ty tz qx qy qz qw``
line per pose (seconds; metres; the unit quaternion of the rotation), the colour camera's optical
centre in the world: camera-to-world. Lines starting with ``#`` are comments.

A motion-capture trajectory is sampled at other times than the colour images (100 Hz against
30 Hz), so a frame's pose is interpolated between the two poses around its time: the translation
linearly, the rotation by slerp. A frame gets no pose when its time is outside the trajectory's
span (no extrapolation) or when the two poses around it are more than ``max_gap`` seconds apart
(``DEFAULT_MAX_GAP``: the mocap lost the camera there, and a straight line through a gap of a
handheld motion is no pose); the reason is returned for the frame's note.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.structures.pose import make_pose, quaternion_to_rotation, slerp

logger = logging.getLogger(__name__)

DEFAULT_MAX_GAP = 0.05  # seconds: five missing samples of a 100 Hz mocap trajectory
TRAJECTORY_FILE = "groundtruth.txt"


@dataclass(frozen=True)
class Trajectory:
    """Poses in time order: ``times`` (N,) seconds, ``positions`` (N, 3) metres, ``quaternions``
    (N, 4) unit ``(qx, qy, qz, qw)``; ``path`` names the file in notes, ``label`` (when given)
    replaces its name there (a bag's pose topic is no file of its own)."""

    times: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    path: Path
    label: str = ""

    @property
    def name(self) -> str:
        return self.label or self.path.name

    def __len__(self) -> int:
        return len(self.times)

    def pose_at(self, t: float, max_gap: float = DEFAULT_MAX_GAP) -> tuple[np.ndarray | None, str]:
        """(the 4 x 4 camera-to-world pose at time ``t``, "") or (None, why there is none)."""
        if not len(self):
            return None, f"{self.path} holds no pose"
        first, last = float(self.times[0]), float(self.times[-1])
        if not first <= t <= last:
            return None, f"time {t:.6f} is outside {self.name}'s span [{first:.6f}, {last:.6f}]"
        hi = int(np.searchsorted(self.times, t, side="left"))
        if self.times[hi] == t:
            return self._pose(self.positions[hi], self.quaternions[hi]), ""
        lo = hi - 1
        gap = float(self.times[hi] - self.times[lo])
        if gap > max_gap:
            return None, (
                f"the poses of {self.name} around time {t:.6f} are {gap:.3f} s apart "
                f"(more than {max_gap:g} s)"
            )
        s = (t - float(self.times[lo])) / gap
        position = (1 - s) * self.positions[lo] + s * self.positions[hi]
        return self._pose(position, slerp(self.quaternions[lo], self.quaternions[hi], s)), ""

    def _pose(self, position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
        return make_pose(quaternion_to_rotation(quaternion, str(self.path)), position)


def frame_pose(
    trajectory: Trajectory | None, t: float, max_gap: float, where: object
) -> tuple[np.ndarray | None, str]:
    """A frame's pose at time ``t`` and "", or None and the note that says why it has none (also a
    warning naming ``where``); (None, "") without a trajectory. One wording for every source."""
    if trajectory is None:
        return None, ""
    pose, why = trajectory.pose_at(t, max_gap)
    if why:
        logger.warning("%s: no pose: %s", where, why)
    return pose, f"no pose: {why}" if why else ""


def trajectory_of(rows: np.ndarray, path: Path, label: str = "") -> Trajectory:
    """A Trajectory of valid ``t tx ty tz qx qy qz qw`` rows, sorted by time (a later row at the
    same time as an earlier one is dropped), quaternions normalised."""
    table = np.asarray(rows, np.float64).reshape(-1, 8)
    table = table[np.argsort(table[:, 0], kind="stable")]
    keep = np.ones(len(table), bool)
    keep[1:] = np.diff(table[:, 0]) > 0
    table = table[keep]
    norms = np.linalg.norm(table[:, 4:], axis=1, keepdims=True)
    return Trajectory(table[:, 0], table[:, 1:4], table[:, 4:] / np.maximum(norms, 1e-12), path, label)


def read_trajectory(path: Path, problems: list[str]) -> Trajectory:
    """The poses of a TUM trajectory file, sorted by time (a later line at the same time as an
    earlier one is dropped); a malformed line goes to ``problems`` as "FILE:LINE: ...". An
    unreadable file is an InputError: a folder that has one is meant to be posed."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    rows: list[np.ndarray] = []
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        where = f"{path}:{number}"
        try:
            values = np.array([float(v) for v in fields], np.float64)
        except ValueError:
            values = np.zeros(0)
        if values.shape != (8,) or not np.isfinite(values).all():
            problems.append(f"{where}: expected 'timestamp tx ty tz qx qy qz qw', got {line.strip()[:60]!r}")
            continue
        try:
            quaternion_to_rotation(values[4:], where)
        except InputError as e:
            problems.append(str(e))
            continue
        rows.append(values)
    return trajectory_of(np.array(rows, np.float64), path)
