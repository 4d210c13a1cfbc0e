"""Gravity direction and R_tilt from a depth map (Gupta, Arbelaez & Malik, CVPR 2013, sec. 3.1).

Indoor scenes are mostly horizontal surfaces (floor, table tops, ceiling) whose normals are
parallel to gravity and vertical ones (walls, cabinet fronts) whose normals are perpendicular
to it. Starting from the camera's y axis (down), each round collects the normals within d degrees
of the current direction (N_par) and within d degrees of its perpendicular plane (N_perp) and
takes as the new direction the unit vector g minimising
    sum_perp (g . n)^2 - sum_par (g . n)^2 = g^T (N_perp^T N_perp - N_par^T N_par) g,
the eigenvector of the smallest eigenvalue; d = 45 degrees for 5 rounds, then 15 for 5.
The local normals come from a3d.runtime.frontend.normals (derivatives of a box-smoothed point map on a
4-pixel grid, exact on planes) rather than Gupta's per-pixel least-squares plane fits: the same
estimate on planar patches at a fraction of the cost.

Camera frame: x right, y down, z forward. The result is R_tilt = R_x(pitch) R_z(roll) (no yaw)
with R_tilt @ g = [0, 1, 0]: the tilt frame's y axis is gravity, pointing down.

Degenerate input never raises and never returns NaN: with too few valid normals (e.g. an
all-zero depth map) the estimate is the identity (status "too_few_normals"); with no floor-like
normals the direction comes from the walls alone (status "walls_only"): exact with two
non-parallel walls; with one wall, the camera's y axis is projected onto the wall's plane.

Real sensor depth (sparse, subsampled, holey) can leave too few normals on the raw map.
``choose_gravity`` is what the pipeline calls; it never fails silently and tries, in this order:

1. ``given``: the frame's own R_tilt (a data set's, an IMU's);
2. ``estimated``: the estimate from the raw depth, when its status is "ok";
3. ``fallback: filled depth (...)``: the estimate from the hole-filled depth, when *it* is "ok"
   (on a3d-synth frames with 90 % of the depth removed it stays within 0.5 degree; the raw
   map gives no normal there: ``python -m bench.gravity_degraded``);
4. ``fallback: walls only (...)``: the dominant vertical planes alone (raw, else filled depth),
   when no floor-like surface is seen by either;
5. ``fallback: camera axes (...)``: the identity, when neither map has enough normals.

Every source but the first two is a fallback: the pipeline writes it into the detections line
and warns once per frame on stderr.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from a3d.runtime.frontend.normals import NormalConfig, normal_grid
from a3d.runtime.structures.geometry import CameraLike, evenly_spread, rtilt_from_pitch_roll

STATUS_OK = "ok"
STATUS_WALLS_ONLY = "walls_only"
STATUS_TOO_FEW_NORMALS = "too_few_normals"


@dataclass(frozen=True)
class GravityConfig:
    """`schedule`: (angle threshold in degrees, rounds) pairs; `min_normals`: fewer valid normals
    give the identity; `min_floor_normals`: fewer floor-like normals in the last round flag the
    estimate as walls only; `max_normals`: the normals are subsampled to at most this many;
    `degenerate_ratio`: eigenvalue gap (relative to the spread) below which the two smallest
    eigenvalues are taken as one (a single wall orientation and no floor)."""

    normals: NormalConfig = field(default_factory=NormalConfig)
    schedule: tuple[tuple[float, int], ...] = ((45.0, 5), (15.0, 5))
    min_normals: int = 100
    min_floor_normals: int = 50
    max_normals: int = 20000
    degenerate_ratio: float = 0.02


@dataclass(frozen=True)
class GravityEstimate:
    """`R_tilt` (3, 3) float64; `gravity` (3,) unit down vector in the camera frame; `status` one
    of "ok", "walls_only", "too_few_normals"; the floor-like and wall-like normal counts of the
    last round."""

    R_tilt: np.ndarray
    gravity: np.ndarray
    status: str
    n_floor: int
    n_wall: int


def rtilt_from_gravity(g: np.ndarray) -> np.ndarray:
    """The R_x(pitch) R_z(roll) rotation taking the camera-frame down vector `g` to [0, 1, 0].

    Row 1 of R_x(a) R_z(b) is [cos a sin b, cos a cos b, -sin a], and it must equal the unit g.
    """
    g = np.asarray(g, dtype=np.float64)
    g = g / np.linalg.norm(g)
    return rtilt_from_pitch_roll(np.arctan2(-g[2], np.hypot(g[0], g[1])), np.arctan2(g[0], g[1]))


def estimate_gravity(
    depth: np.ndarray, K: CameraLike, config: GravityConfig = GravityConfig()
) -> GravityEstimate:
    """Gupta et al.'s iterative gravity estimate from an (H, W) metric depth map (0 = missing)."""
    grid = normal_grid(depth, K, config.normals)
    normals = grid.normals[grid.valid].astype(np.float64)
    normals = evenly_spread(normals, config.max_normals)
    g = np.array([0.0, 1.0, 0.0])
    if len(normals) < config.min_normals:
        return GravityEstimate(np.eye(3), g, STATUS_TOO_FEW_NORMALS, 0, 0)
    n_floor = n_wall = 0
    for degrees, rounds in config.schedule:
        cos_t, sin_t = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
        for _ in range(rounds):
            c = np.abs(normals @ g)
            floor, wall = c > cos_t, c < sin_t
            n_floor, n_wall = int(floor.sum()), int(wall.sum())
            if n_floor + n_wall == 0:
                break
            sign = wall.astype(np.float64) - floor  # +1 wall-like, -1 floor-like, 0 neither
            g = _smallest_direction((normals * sign[:, None]).T @ normals, g, config.degenerate_ratio)
    status = STATUS_OK if n_floor >= config.min_floor_normals else STATUS_WALLS_ONLY
    return GravityEstimate(rtilt_from_gravity(g), g, status, n_floor, n_wall)


GRAVITY_GIVEN = "given"
GRAVITY_ESTIMATED = "estimated"
FALLBACK_PREFIX = "fallback: "


@dataclass(frozen=True)
class GravityChoice:
    """The R_tilt a frame uses and where it came from: ``source`` is "given", "estimated" or
    "fallback: <method> (<why the better ones failed>)" (see the module docstring)."""

    R_tilt: np.ndarray
    source: str

    @property
    def is_fallback(self) -> bool:
        return self.source.startswith(FALLBACK_PREFIX)


def choose_gravity(
    depth: np.ndarray,
    filled: np.ndarray,
    K: CameraLike,
    given: np.ndarray | None = None,
    config: GravityConfig = GravityConfig(),
) -> GravityChoice:
    """The frame's R_tilt by the documented order: given, raw depth, filled depth, walls, camera axes.

    ``depth`` the raw metric depth (0 = missing), ``filled`` its hole-filled version
    (a3d.runtime.frontend.depth.fill_depth; all zeros when the frame has no depth at all)."""
    if given is not None:
        return GravityChoice(np.asarray(given, np.float64), GRAVITY_GIVEN)
    raw = estimate_gravity(depth, K, config)
    if raw.status == STATUS_OK:
        return GravityChoice(raw.R_tilt, GRAVITY_ESTIMATED)
    why = f"raw depth: {_weakness(raw)}"
    dense = estimate_gravity(filled, K, config)
    if dense.status == STATUS_OK:
        return GravityChoice(dense.R_tilt, f"{FALLBACK_PREFIX}filled depth ({why})")
    why = f"{why}; filled depth: {_weakness(dense)}"
    for estimate in (raw, dense):
        if estimate.status == STATUS_WALLS_ONLY:
            return GravityChoice(estimate.R_tilt, f"{FALLBACK_PREFIX}walls only ({why})")
    return GravityChoice(np.eye(3), f"{FALLBACK_PREFIX}camera axes ({why})")


def _weakness(estimate: GravityEstimate) -> str:
    if estimate.status == STATUS_TOO_FEW_NORMALS:
        return "too few surface normals"
    return f"no floor-like surface ({estimate.n_floor} normals)"


def estimate_rtilt(depth: np.ndarray, K: CameraLike, config: GravityConfig = GravityConfig()) -> np.ndarray:
    """(3, 3) R_tilt = R_x R_z with R_tilt @ gravity = [0, 1, 0]; see estimate_gravity for flags."""
    return estimate_gravity(depth, K, config).R_tilt


def _smallest_direction(a: np.ndarray, previous: np.ndarray, degenerate_ratio: float) -> np.ndarray:
    """Unit eigenvector of the symmetric `a` with the smallest eigenvalue, signed like `previous`.

    When the two smallest eigenvalues are (nearly) equal the minimiser is a whole plane: take the
    projection of `previous` onto it, the closest direction the data allow.
    """
    values, vectors = np.linalg.eigh(a)
    spread = values[2] - values[0]
    if spread <= 0:
        return previous
    if values[1] - values[0] < degenerate_ratio * spread:
        plane = vectors[:, :2]
        g = plane @ (plane.T @ previous)
        norm = np.linalg.norm(g)
        g = g / norm if norm > 1e-9 else vectors[:, 0]
    else:
        g = vectors[:, 0]
    return g if g @ previous >= 0 else -g
