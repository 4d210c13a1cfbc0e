"""Camera, 3D-box and 2D-box geometry of a3d: pure numpy (float64), no torch, no scipy.

Conventions (docs/conventions.md "Camera and tilt frames" and "3D boxes"):

* Camera frame: x right, y down, z forward, metres. Pixel ``(u, v)`` (column, row) has its
  centre at ``(u, v)``; a pixel with depth ``z`` back-projects to ``x = (u - cx) z / fx``,
  ``y = (v - cy) z / fy``.
* Tilt frame: ``p_tilt = R_tilt @ p_cam`` with ``R_tilt = R_x(pitch) @ R_z(roll)`` (no yaw), so
  tilt-frame ``y`` is parallel to gravity (pointing down). ``R_x(a) = [[1,0,0],[0,c,-s],[0,s,c]]``,
  ``R_z(b) = [[c,-s,0],[s,c,0],[0,0,1]]``: a camera looking down at the floor has a negative
  pitch, a camera rolled clockwise (as seen from behind) a positive roll.
* 3D box ``[x, y, z, l, w, h, theta]``: centre in the camera frame; ``l >= w`` horizontal extents,
  ``h`` the extent along tilt-frame y; ``theta`` in ``[-pi/2, pi/2]`` the yaw in the tilt frame,
  ``atan2(dx, dz)`` of the orientation vector (horizontal, perpendicular to the long edge).
  ``theta`` and ``theta - pi`` are the same box, as are ``(l, w, theta)`` and ``(w, l, theta + pi/2)``.
* Corner order (that of the authors' ``calc_corners_tilt.m``): local corners ``(+-l/2, +-h/2, +-w/2)``
  in (x, y, z) are, in order, ``(+l,+h,+w) (-l,+h,+w) (-l,+h,-w) (+l,+h,-w)`` then the same four
  with ``-h``: corners 0-3 are the lower face (y down), 4-7 the upper face in the same order, and
  each face runs once around the footprint (counter-clockwise in the tilt-frame (x, z) plane).
  They are rotated about y by ``[[cos t, 0, sin t], [0, 1, 0], [-sin t, 0, cos t]]`` and shifted
  to the tilt-frame centre ``R_tilt @ [x, y, z]``; camera-frame corners are ``R_tilt.T @ p_tilt``.
* 2D boxes ``[x1, y1, x2, y2]`` are continuous pixel coordinates, area ``(x2 - x1) * (y2 - y1)``
  (no "+1"); an image of width ``W`` spans ``[-0.5, W - 0.5]``.
* Horizontal flip: ``u -> W - 1 - u``, ``cx -> W - 1 - cx``, camera ``x -> -x``, ``theta -> -theta``,
  ``R_tilt -> F R_tilt F`` with ``F = diag(-1, 1, 1)`` (it negates the roll).

Bad values (wrong shapes, NaN/inf, negative sizes, a matrix that is no rotation) raise
``InputError`` (a ValueError) with a one-line message; nothing returns NaN silently.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.structures.boxes import BOX_DIM, CENTER, SIZE, THETA, H, L, W, X, local_half_sizes

NEAR_PLANE_M = 0.05  # box edges are clipped at z = 0.05 m before projection
_MAX_ABS_METRES = 1e6  # 3D box values beyond this are corrupt data (see _boxes)
_MAX_ABS_PIXELS = 1e8
_CLIP_CHUNK = 8192  # polygon-clipping pairs per chunk (memory: 64 vertices per pair after 4 clips)

# Local corner signs (l, h, w) in the documented order; BOX_EDGES index into it.
_CORNER_SIGNS = np.array(
    [[1, 1, 1], [-1, 1, 1], [-1, 1, -1], [1, 1, -1], [1, -1, 1], [-1, -1, 1], [-1, -1, -1], [1, -1, -1]],
    dtype=np.float64,
)
BOX_EDGES = np.array(
    [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]],
    dtype=np.int64,
)


# ----------------------------------------------------------------------------- camera intrinsics


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (README pixel convention: pixel centres at integers)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise InputError(f"intrinsics: {name} must be a number, got {value!r}")
            if not math.isfinite(float(value)):
                raise InputError(f"intrinsics: {name} is not finite ({value})")
            object.__setattr__(self, name, float(value))
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(f"intrinsics: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict[str, float]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> Intrinsics:
        """From ``{"fx", "fy", "cx", "cy"}`` (other keys are ignored); InputError names what is missing."""
        if not isinstance(d, Mapping):
            raise InputError(f"intrinsics: expected an object with fx, fy, cx, cy, got {type(d).__name__}")
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in d]
        if missing:
            raise InputError(f"intrinsics: missing {', '.join(missing)}")
        return cls(fx=d["fx"], fy=d["fy"], cx=d["cx"], cy=d["cy"])  # type: ignore[arg-type]

    @classmethod
    def from_matrix(cls, K: np.ndarray) -> Intrinsics:
        """From a 3x3 camera matrix (zero skew)."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise InputError(f"intrinsics: camera matrix must be 3x3, got shape {K.shape}")
        return cls(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])

    def resized(self, sx: float, sy: float) -> Intrinsics:
        """The same camera for its image resized by ``sx`` across and ``sy`` down (the README pixel
        convention: ``x -> (x + 0.5) sx - 0.5``)."""
        return Intrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5)


NYU_CROP_INTRINSICS = Intrinsics(fx=518.857901, fy=519.469611, cx=325.582449 - 40.0, cy=253.736166 - 44.0)
NYU_CROP_SIZE = (427, 561)  # (H, W) of the NYUv2 standard crop, rows 44..470, cols 40..600

CameraLike = Intrinsics | np.ndarray


def _intrinsics(K: CameraLike) -> Intrinsics:
    return K if isinstance(K, Intrinsics) else Intrinsics.from_matrix(K)


def _finite_result(out: np.ndarray, what: str) -> np.ndarray:
    """out, or InputError when NaN/inf inputs or overflow made it non-finite."""
    if not np.all(np.isfinite(out)):
        raise InputError(f"{what}: NaN or infinite result (NaN/inf input, or values far out of range)")
    return out


def backproject(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: CameraLike) -> np.ndarray:
    """Camera-frame points (..., 3) of pixels (u, v) at depth z (broadcast together)."""
    k = _intrinsics(K)
    u, v, z = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (u, v, z)))
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], axis=-1)
    return _finite_result(out, "backproject")


def backproject_depth(depth: np.ndarray, K: CameraLike) -> np.ndarray:
    """Point map (H, W, 3) of a depth map in metres; pixels with depth 0 map to the origin."""
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InputError(f"depth: expected an (H, W) map, got shape {depth.shape}")
    rows, cols = np.indices(depth.shape, dtype=np.float64)
    return backproject(cols, rows, depth, K)


def project_points(points: np.ndarray, K: CameraLike) -> np.ndarray:
    """Pixel coordinates (..., 2) = (u, v) of camera-frame points (..., 3), which must have z > 0.

    Points at or behind the camera have no image; clip them first (``box_edges_clipped``).
    """
    k = _intrinsics(K)
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise InputError(f"points: expected shape (..., 3), got {p.shape}")
    z = p[..., 2]
    if not np.all(z > 0):
        raise InputError(f"points: {int(np.sum(~(z > 0)))} point(s) with z <= 0 or NaN cannot be projected")
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.stack([k.fx * p[..., 0] / z + k.cx, k.fy * p[..., 1] / z + k.cy], axis=-1)
    return _finite_result(out, "project_points")


def depth_seen_at(
    points: np.ndarray, depth: np.ndarray, K: CameraLike, stride: int = 1, near_m: float = 0.0
) -> np.ndarray:
    """(...,) the depth a depth map measured where each camera-frame point (..., 3) projects: ``K``
    the full frame's, ``depth`` (h, w) its every ``stride``-th pixel each way. 0 where the point is
    not more than ``near_m`` ahead of the camera, projects off the map, or the map has no depth
    there: what says whether the camera saw a point, or through it."""
    p = np.asarray(points, np.float64)
    ahead = p[..., 2] > near_m
    uv = np.full((*p.shape[:-1], 2), -1.0)
    uv[ahead] = project_points(p[ahead], K) / stride
    u, v = np.round(uv[..., 0]).astype(np.int64), np.round(uv[..., 1]).astype(np.int64)
    height, width = depth.shape
    on = ahead & (u >= 0) & (v >= 0) & (u < width) & (v < height)
    return np.where(on, depth[np.clip(v, 0, height - 1), np.clip(u, 0, width - 1)], 0.0)


# ----------------------------------------------------------------------------- gravity rotation


def rtilt_from_pitch_roll(pitch: float, roll: float) -> np.ndarray:
    """``R_tilt = R_x(pitch) @ R_z(roll)`` (radians; see the module docstring for signs)."""
    if not (math.isfinite(pitch) and math.isfinite(roll)):
        raise InputError(f"R_tilt: pitch and roll must be finite angles, got {pitch}, {roll}")
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    r_z = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return r_x @ r_z


def pitch_roll_from_rtilt(R: np.ndarray, tol: float = 1e-4) -> tuple[float, float]:
    """(pitch, roll) in radians of ``R = R_x(pitch) R_z(roll)``; InputError if R has a yaw part."""
    R = check_rotation(R, "R_tilt", tol)
    # R_x(a) R_z(b) = [[cb, -sb, 0], [ca sb, ca cb, -sa], [sa sb, sa cb, ca]]
    if abs(R[0, 2]) > tol:
        raise InputError(f"R_tilt: not of the form R_x(pitch) R_z(roll) (R[0, 2] = {R[0, 2]:.3g}, a yaw)")
    return math.atan2(-R[1, 2], R[2, 2]), math.atan2(-R[0, 1], R[0, 0])


def is_rotation(R: np.ndarray, tol: float = 1e-4) -> bool:
    """True for a finite 3x3 matrix with ``R R^T = I`` and ``det R = 1`` to within tol."""
    R = np.asarray(R)
    if R.shape != (3, 3) or not np.issubdtype(R.dtype, np.number) or not np.all(np.isfinite(R)):
        return False
    R = R.astype(np.float64)
    if np.max(np.abs(R)) > 1.0 + tol:  # entries of a rotation are within [-1, 1]
        return False
    return bool(np.max(np.abs(R @ R.T - np.eye(3))) <= tol and abs(np.linalg.det(R) - 1.0) <= tol)


def check_rotation(R: np.ndarray, what: str, tol: float = 1e-4) -> np.ndarray:
    """R as float64 (3, 3) if it is a proper rotation, else InputError ``"what: ..."``."""
    arr = np.asarray(R)
    if arr.shape != (3, 3):
        raise InputError(f"{what}: expected a 3x3 rotation matrix, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
        raise InputError(f"{what}: rotation matrix has non-numeric, NaN or infinite entries")
    if not is_rotation(arr, tol):
        with np.errstate(all="ignore"):
            err, det = np.max(np.abs(arr @ arr.T - np.eye(3))), np.linalg.det(arr)
        raise InputError(f"{what}: not a proper rotation (max |R R^T - I| = {err:.3g}, det = {det:.6g})")
    return arr.astype(np.float64)


# ----------------------------------------------------------------------------- 7-vectors and corners


def _boxes(boxes: np.ndarray, width: int, what: str, limit: float) -> np.ndarray:
    """(N, width) float64 view of boxes, or InputError for a wrong shape, NaN/inf or |value| > limit.

    The limit (far beyond any camera's range) keeps products of sizes and coordinates from
    overflowing into inf/NaN: such values can only come from corrupt data.
    """
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, width)
    if arr.ndim != 2 or arr.shape[1] != width:
        raise InputError(f"{what}: expected shape (N, {width}), got {arr.shape}")
    bad = ~(np.abs(arr) <= limit).all(axis=1)  # NaN fails the comparison too
    if np.any(bad):
        raise InputError(f"{what}: {int(np.sum(bad))} box(es) with NaN, inf or values beyond +-{limit:g}")
    return arr


def _boxes2d(boxes: np.ndarray, what: str = "boxes2d") -> np.ndarray:
    return _boxes(boxes, 4, what, _MAX_ABS_PIXELS)


def _boxes3d(boxes: np.ndarray, what: str = "boxes3d") -> np.ndarray:
    arr = _boxes(boxes, BOX_DIM, what, _MAX_ABS_METRES)
    if np.any(arr[:, SIZE] < 0):
        bad = int(np.sum((arr[:, SIZE] < 0).any(axis=1)))
        raise InputError(f"{what}: negative size (l, w, h) in {bad} box(es)")
    return arr


def wrap_half_pi(theta: np.ndarray | float) -> np.ndarray:
    """theta modulo pi, in [-pi/2, pi/2] (a box's yaw is defined modulo pi)."""
    t = np.asarray(theta, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise InputError("theta: NaN or infinite angle")
    return np.clip(t - np.pi * np.round(t / np.pi), -np.pi / 2, np.pi / 2)


def canonical_boxes(boxes: np.ndarray) -> np.ndarray:
    """The same boxes with l >= w (swapping l and w turns theta by pi/2) and theta in [-pi/2, pi/2]."""
    out = _boxes3d(boxes).copy()
    swap = out[:, L] < out[:, W]
    out[swap, L], out[swap, W] = out[swap, W], out[swap, L]
    out[swap, 6] += np.pi / 2
    out[:, THETA] = wrap_half_pi(out[:, THETA])
    return out


def box_corners_tilt(boxes: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    """Corners (N, 8, 3) in the tilt frame, in the module's corner order."""
    b = _boxes3d(boxes)
    R = check_rotation(R_tilt, "R_tilt")
    local = _CORNER_SIGNS[None] * local_half_sizes(b)[:, None, :]  # (N, 8, 3): (x, y, z) = (l, h, w) / 2
    return turned_by_yaw(local, b[:, THETA, None]) + (b[:, CENTER] @ R.T)[:, None, :]


def turned_by_yaw(local: np.ndarray, theta: np.ndarray | float) -> np.ndarray:
    """Offsets (..., 3) in a box's own axes (along l, h, w) as tilt-frame offsets for yaw ``theta``
    (broadcast against ``local[..., 0]``): the box's rotation about gravity."""
    c, s = np.cos(theta), np.sin(theta)
    x, y, z = local[..., 0], local[..., 1], local[..., 2]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=-1)


def box_corners_camera(boxes: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    """Corners (N, 8, 3) in the camera frame (``R_tilt.T @ tilt corners``), same order."""
    return box_corners_tilt(boxes, R_tilt) @ check_rotation(R_tilt, "R_tilt")


def boxes_from_corners_tilt(corners: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    """7-vectors (N, 7) of boxes given by 8 tilt-frame corners in the module's corner order.

    As the authors' release (``VectorizeBboxes.m``) converts its annotations: centre = mean of
    the corners taken to the camera frame; h = length of the vertical edges (0-4 ...), the two
    horizontal edge lengths (0-1 and 0-3) give l >= w; the orientation vector is the horizontal
    edge perpendicular to the long side, ``theta = atan2(dx, dz)`` wrapped to [-pi/2, pi/2]
    (radians; the release's script returns degrees). Each length and direction is averaged over
    the four parallel edges, which is the release's value for exact boxes and a fit for slightly
    non-rectangular ones. A square footprint takes the 0-3 edge as its orientation vector.
    """
    c = np.asarray(corners, dtype=np.float64)
    if c.ndim != 3 or c.shape[1:] != (8, 3):
        raise InputError(f"corners: expected shape (N, 8, 3), got {c.shape}")
    if not np.all(np.abs(c) <= _MAX_ABS_METRES):
        raise InputError(f"corners: NaN, infinite or beyond +-{_MAX_ABS_METRES:g} coordinates")
    R = check_rotation(R_tilt, "R_tilt")
    edges_1 = c[:, [0, 3, 4, 7]] - c[:, [1, 2, 5, 6]]  # the four edges parallel to 1 -> 0
    edges_3 = c[:, [0, 1, 4, 5]] - c[:, [3, 2, 7, 6]]  # the four edges parallel to 3 -> 0
    len_1 = np.linalg.norm(edges_1, axis=2).mean(axis=1)
    len_3 = np.linalg.norm(edges_3, axis=2).mean(axis=1)
    height = np.linalg.norm(c[:, :4] - c[:, 4:], axis=2).mean(axis=1)
    orient = np.where((len_1 >= len_3)[:, None], edges_3.mean(axis=1), edges_1.mean(axis=1))
    theta = wrap_half_pi(np.arctan2(orient[:, 0], orient[:, 2]))
    centre = c.mean(axis=1) @ R  # R.T @ p for row vectors
    return np.column_stack([centre, np.maximum(len_1, len_3), np.minimum(len_1, len_3), height, theta])


# ----------------------------------------------------------------------------- horizontal flip


def flip_boxes_3d(boxes: np.ndarray) -> np.ndarray:
    """Mirror 3D boxes for a horizontal image flip: camera x -> -x, theta -> -theta."""
    out = _boxes3d(boxes).copy()
    out[:, X] = -out[:, X]
    out[:, THETA] = -out[:, THETA]
    return out


def flip_rtilt(R_tilt: np.ndarray) -> np.ndarray:
    """``F R_tilt F`` with ``F = diag(-1, 1, 1)``: the flipped image's gravity rotation (roll negated)."""
    F = np.diag([-1.0, 1.0, 1.0])
    return F @ check_rotation(R_tilt, "R_tilt") @ F


def flip_intrinsics(K: CameraLike, width: int) -> CameraLike:
    """Intrinsics of the horizontally flipped image: cx -> W - 1 - cx (same type as given)."""
    width = _width(width)
    if isinstance(K, Intrinsics):
        return Intrinsics(fx=K.fx, fy=K.fy, cx=width - 1 - K.cx, cy=K.cy)
    out = _intrinsics(K).matrix()
    out[0, 2] = width - 1 - out[0, 2]
    return out


def flip_boxes_2d(boxes: np.ndarray, width: int) -> np.ndarray:
    """Mirror 2D boxes for a horizontal flip of an image W pixels wide: x -> W - 1 - x."""
    b, width = _boxes2d(boxes), _width(width)
    return np.column_stack([width - 1 - b[:, 2], b[:, 1], width - 1 - b[:, 0], b[:, 3]])


# ----------------------------------------------------------------------------- projection to 2D


def _image_size(image_size: tuple[int, int]) -> tuple[int, int]:
    size = np.asarray(image_size)
    if size.shape != (2,) or not np.issubdtype(size.dtype, np.integer) or np.any(size <= 0):
        raise InputError(f"image_size: expected two positive integers (H, W), got {image_size!r}")
    return int(size[0]), int(size[1])


def _width(width: int) -> int:
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width <= 0:
        raise InputError(f"width: expected a positive integer image width, got {width!r}")
    return int(width)


def box_edges_clipped(
    boxes: np.ndarray, R_tilt: np.ndarray, near: float = NEAR_PLANE_M
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame edges (N, 12, 2, 3) of the boxes (``BOX_EDGES`` order) cut at the plane z = near.

    The part of an edge behind the plane is dropped; ``valid`` (N, 12) is False for edges wholly
    behind it (their coordinates are then meaningless but finite). Valid endpoints have z >= near.
    """
    if not (math.isfinite(near) and near > 0):
        raise InputError(f"near plane: expected a positive distance in metres, got {near}")
    corners = box_corners_camera(boxes, R_tilt)
    a, b = corners[:, BOX_EDGES[:, 0]], corners[:, BOX_EDGES[:, 1]]
    za, zb = a[..., 2:], b[..., 2:]
    a_in, b_in = za >= near, zb >= near
    crossing = a_in != b_in  # then za != zb, so the division is safe
    t = np.where(crossing, (near - za) / np.where(crossing, zb - za, 1.0), 0.0)
    cut = a + t * (b - a)
    cut[..., 2] = near
    seg = np.stack([np.where(a_in, a, cut), np.where(b_in, b, cut)], axis=2)
    return seg, (a_in | b_in)[..., 0]


def project_boxes_to_2d(
    boxes: np.ndarray, R_tilt: np.ndarray, K: CameraLike, image_size: tuple[int, int]
) -> np.ndarray:
    """Amodal 2D boxes (N, 4): extent of the projected box, clipped to the image.

    The 12 edges are cut at the near plane z = 0.05 m first (the vertices of the cut box are the
    cut edges' endpoints), so boxes straddling the camera project correctly. Boxes with nothing
    in front of the near plane get the empty box ``[-0.5, -0.5, -0.5, -0.5]``; boxes wholly
    outside the image get a zero-area box on its border.
    """
    H, W = _image_size(image_size)
    seg, valid = box_edges_clipped(boxes, R_tilt)
    n = len(seg)
    pts = seg.reshape(n, 24, 3)
    ok = np.repeat(valid, 2, axis=1)
    pts = np.where(ok[..., None], pts, np.array([0.0, 0.0, 1.0]))  # placeholder in front of the camera
    uv = project_points(pts, K)
    lo = np.where(ok[..., None], uv, np.inf).min(axis=1)
    hi = np.where(ok[..., None], uv, -np.inf).max(axis=1)
    out = np.full((n, 4), -0.5)
    seen = ok.any(axis=1)
    limits = np.array([W - 0.5, H - 0.5])
    out[seen, :2] = np.clip(lo[seen], -0.5, limits)
    out[seen, 2:] = np.clip(hi[seen], -0.5, limits)
    return out


def evenly_spread(points: np.ndarray, limit: int) -> np.ndarray:
    """At most ``limit`` of ``points`` (rows), every k-th, so that they spread over all of them: a
    fit on many depth samples holds to the same answer on a fixed number of them."""
    return points[:: max(1, -(-len(points) // limit))]


def points_in_box(
    points: np.ndarray, box: np.ndarray, R_tilt: np.ndarray, margin_m: float = 0.0, bottom_m: float = 0.0
) -> np.ndarray:
    """Which tilt-frame points (..., 3) lie in ``box`` (camera-frame centre, yaw in the tilt frame of
    ``R_tilt``) grown by ``margin_m`` on its sides and top, its bottom face moved down by
    ``bottom_m`` (y is down; a negative one raises it)."""
    d = points - np.asarray(R_tilt) @ box[CENTER]
    c, s = np.cos(box[THETA]), np.sin(box[THETA])
    along_l, along_w = c * d[..., 0] - s * d[..., 2], s * d[..., 0] + c * d[..., 2]
    return (
        (np.abs(along_l) <= box[L] / 2 + margin_m)
        & (np.abs(along_w) <= box[W] / 2 + margin_m)
        & (d[..., 1] >= -box[H] / 2 - margin_m)
        & (d[..., 1] <= box[H] / 2 + bottom_m)
    )


# ----------------------------------------------------------------------------- 2D boxes


def pixel_window(box2d: np.ndarray, size: tuple[int, int]) -> tuple[slice, slice]:
    """The rows and columns of the pixels whose centres lie in a 2D box (README pixel convention)."""
    x1, y1, x2, y2 = box2d
    cols = slice(max(int(np.ceil(x1)), 0), min(int(np.floor(x2)), size[1] - 1) + 1)
    rows = slice(max(int(np.ceil(y1)), 0), min(int(np.floor(y2)), size[0] - 1) + 1)
    return rows, cols


def box_area_2d(boxes: np.ndarray, plus_one: bool = False) -> np.ndarray:
    """Areas (N,) of 2D boxes, ``(x2 - x1) * (y2 - y1)``, 0 for empty or inverted boxes.

    ``plus_one``: ``(x2 - x1 + 1) * (y2 - y1 + 1)``, the inclusive-pixel convention of Fast R-CNN's
    and the Deng & Latecki release's ``nms.m`` (their boxes name first and last pixels, not edges).
    """
    b = _boxes2d(boxes)
    one = 1.0 if plus_one else 0.0
    return np.maximum(b[:, 2] - b[:, 0] + one, 0.0) * np.maximum(b[:, 3] - b[:, 1] + one, 0.0)


def iou_2d(a: np.ndarray, b: np.ndarray, plus_one: bool = False) -> np.ndarray:
    """IoU matrix (N, M) of 2D boxes in continuous coordinates (no +1); 0 when the union is empty.

    ``plus_one``: widths and heights ``x2 - x1 + 1`` (see ``box_area_2d``), in the same order of
    operations as the release's ``nms.m``, so that its overlaps are reproduced to the last bit.
    """
    a, b = _boxes2d(a, "boxes2d a"), _boxes2d(b, "boxes2d b")
    one = 1.0 if plus_one else 0.0
    iw = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]) + one
    ih = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]) + one
    inter = np.maximum(iw, 0.0) * np.maximum(ih, 0.0)
    union = box_area_2d(a, plus_one)[:, None] + box_area_2d(b, plus_one)[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def context_boxes(boxes: np.ndarray, image_size: tuple[int, int], scale: float = 1.5) -> np.ndarray:
    """Boxes scaled by ``scale`` about their centres and clipped to the image (the context RoIs)."""
    H, W = _image_size(image_size)
    b = _boxes2d(boxes)
    if not (math.isfinite(scale) and scale > 0):
        raise InputError(f"context_boxes: scale must be a positive number, got {scale}")
    centre = (b[:, :2] + b[:, 2:]) / 2.0
    half = (b[:, 2:] - b[:, :2]) * (scale / 2.0)
    limits = np.array([W - 0.5, H - 0.5])
    return np.hstack([np.clip(centre - half, -0.5, limits), np.clip(centre + half, -0.5, limits)])


def _greedy_nms(
    boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray | None, thr: float, plus_one: bool
) -> np.ndarray:
    b = _boxes2d(boxes)
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if len(s) != len(b) or (labels is not None and len(labels) != len(b)):
        counts = f"{len(s)} scores" + ("" if labels is None else f", {len(labels)} labels")
        raise InputError(f"nms: {len(b)} boxes but {counts}")
    if not np.all(np.isfinite(s)):
        raise InputError("nms: NaN or infinite scores")
    if not math.isfinite(thr):
        raise InputError(f"nms: the IoU threshold must be a number, got {thr}")
    order = np.argsort(-s, kind="stable")  # descending score, ties by index
    groups = [order] if labels is None else [order[labels[order] == v] for v in np.unique(labels)]
    kept = np.concatenate([g[_keep_in_group(b[g], thr, plus_one)] for g in groups]) if len(order) else order
    return kept[np.lexsort((kept, -s[kept]))].astype(np.int64)


_MATRIX_NMS_LIMIT = 4000  # boxes per label above which the IoU matrix would be too large


def _keep_in_group(boxes: np.ndarray, thr: float, plus_one: bool) -> np.ndarray:
    """Greedy keep mask of boxes already sorted by descending score.

    Up to _MATRIX_NMS_LIMIT boxes: from the matrix ``sup[i, j]`` = "i, ranked before j, overlaps
    j by more than thr", decided in rounds: keep every undecided box that no undecided or kept box
    suppresses, drop every box a kept box suppresses. This is exactly the greedy result (a box is
    kept iff no kept box ranked before it suppresses it), in as many rounds as the longest
    suppression chain instead of one Python step per kept box.
    """
    n = len(boxes)
    if n > _MATRIX_NMS_LIMIT:
        return _keep_in_group_loop(boxes, thr, plus_one)
    sup = np.triu(iou_2d(boxes, boxes, plus_one) > thr, 1)
    kept = ~sup.any(axis=0)
    removed = np.zeros(n, dtype=bool)
    while True:
        removed |= sup[kept].any(axis=0)
        newly = ~(kept | removed) & ~sup[~removed].any(axis=0)
        if not newly.any():
            return kept
        kept |= newly


def _keep_in_group_loop(boxes: np.ndarray, thr: float, plus_one: bool) -> np.ndarray:
    """The plain greedy loop, one vectorised IoU row per kept box (for very large groups)."""
    keep = np.zeros(len(boxes), dtype=bool)
    rest = np.arange(len(boxes))
    while rest.size:
        i, rest = rest[0], rest[1:]
        keep[i] = True
        rest = rest[iou_2d(boxes[i : i + 1], boxes[rest], plus_one)[0] <= thr]
    return keep


def nms_2d(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float, plus_one: bool = False) -> np.ndarray:
    """Greedy NMS: indices kept, by descending score (ties: lower index first).

    A box is dropped when its continuous IoU with a kept, higher-scored box is > iou_threshold
    (Fast R-CNN's ``nms``, without its "+1"; ``plus_one`` puts it back, see ``iou_2d``). Not
    cv2.dnn.NMSBoxes: that one drops scores <= 0 (its score threshold must be >= 0 and is
    strict), works on float32 scores, and calls two empty boxes IoU 1.
    """
    return _greedy_nms(boxes, scores, None, float(iou_threshold), plus_one)


def batched_nms_2d(
    boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray, iou_threshold: float, plus_one: bool = False
) -> np.ndarray:
    """``nms_2d`` within each label (boxes of different labels never suppress each other)."""
    return _greedy_nms(boxes, scores, np.asarray(labels).reshape(-1), float(iou_threshold), plus_one)


# ----------------------------------------------------------------------------- 3D IoU


def _footprints(boxes: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tilt-frame footprint centres (N, 2) and corners (N, 4, 2) in (x, z), and y ranges (N, 2)."""
    centre = boxes[:, CENTER] @ R.T
    c, s = np.cos(boxes[:, THETA])[:, None], np.sin(boxes[:, THETA])[:, None]
    lx = _CORNER_SIGNS[None, :4, 0] * boxes[:, L, None] / 2.0
    lz = _CORNER_SIGNS[None, :4, 2] * boxes[:, W, None] / 2.0
    foot = np.stack([c * lx + s * lz, -s * lx + c * lz], axis=-1) + centre[:, None, [0, 2]]
    half_h = boxes[:, H, None] / 2.0
    return centre[:, [0, 2]], foot, centre[:, 1:2] + np.hstack([-half_h, half_h]), np.hstack([c, s])


def _next(a: np.ndarray) -> np.ndarray:
    """Values of the next vertex around each polygon (last axis, cyclic)."""
    return np.concatenate([a[..., 1:], a[..., :1]], axis=-1)


def _rect_intersection_area(poly: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Areas (P,) of polygons ``poly`` (2, P, K) = (x, z) rows, counter-clockwise, cut by the
    centred rectangles ``|x| <= half[0], |z| <= half[1]`` (half: (2, P, 1)).

    Sutherland-Hodgman in fixed-size arrays: each cut by one rectangle side maps every vertex to
    two (itself, or for an outside vertex a point on the cut line; then the edge's crossing point,
    put exactly on the line, or a repeat). The stretches of the result that lie on the cut line
    enclose no area, so the shoelace area is that of the truly cut polygon. Every decision is one
    sign test of one vertex against one line, so touching and collinear edges (vertices on the line
    up to rounding) move the area by rounding only, never by a whole piece.
    """
    for axis, sign in ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)):
        p, q = poly[axis], poly[1 - axis]  # tested coordinate, the other one
        line = sign * half[axis]
        d = half[axis] - sign * p  # >= 0 inside
        inside = d >= 0
        d_next = _next(d)
        crossing = inside != (d_next >= 0)  # then d != d_next
        t = d / np.where(crossing, d - d_next, 1.0)
        kept_p, kept_q = np.where(inside, p, line), np.where(inside, q, 0.0)
        out = np.empty((2, p.shape[0], 2 * p.shape[1]))
        out[axis, :, 0::2], out[1 - axis, :, 0::2] = kept_p, kept_q
        out[axis, :, 1::2] = np.where(crossing, line, kept_p)
        out[1 - axis, :, 1::2] = np.where(crossing, q + t * (_next(q) - q), kept_q)
        poly = out
    x, z = poly
    return np.maximum(0.5 * np.sum(x * _next(z) - _next(x) * z, axis=1), 0.0)


def iou_3d(a: np.ndarray, b: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    """3D IoU matrix (N, M) of boxes rotated about gravity, both sets in one camera frame.

    Intersection = area of the footprints' intersection in the tilt-frame (x, z) plane times the
    overlap of the tilt-frame y ranges (docs/conventions.md "Evaluation"); union = sum of volumes minus it.
    Pairs whose y ranges or circumscribed footprint circles do not overlap are skipped before any
    polygon work. Each remaining footprint of ``a`` is cut by that of ``b`` in ``b``'s own frame
    (an axis-aligned rectangle there). Zero-volume boxes have IoU 0.
    """
    a, b = _boxes3d(a, "boxes3d a"), _boxes3d(b, "boxes3d b")
    R = check_rotation(R_tilt, "R_tilt")
    out = np.zeros((len(a), len(b)))
    if out.size == 0:
        return out
    ca, fa, ya, _ = _footprints(a, R)
    cb, _, yb, cos_sin_b = _footprints(b, R)
    vol_a, vol_b = a[:, 3] * a[:, 4] * a[:, 5], b[:, 3] * b[:, 4] * b[:, 5]
    dy = np.minimum(ya[:, None, 1], yb[None, :, 1]) - np.maximum(ya[:, None, 0], yb[None, :, 0])
    dist2 = np.sum((ca[:, None, :] - cb[None, :, :]) ** 2, axis=-1)
    radii = np.hypot(a[:, 3], a[:, 4])[:, None] / 2.0 + np.hypot(b[:, 3], b[:, 4])[None, :] / 2.0
    cand = (dy > 0) & (dist2 < radii**2) & (vol_a[:, None] > 0) & (vol_b[None, :] > 0)
    ia, ib = np.nonzero(cand)
    for start in range(0, len(ia), _CLIP_CHUNK):
        i, j = ia[start : start + _CLIP_CHUNK], ib[start : start + _CLIP_CHUNK]
        rel = fa[i] - cb[j][:, None, :]  # a's corners about b's centre, then in b's frame
        c, s = cos_sin_b[j, 0:1], cos_sin_b[j, 1:2]
        poly = np.stack([c * rel[..., 0] - s * rel[..., 1], s * rel[..., 0] + c * rel[..., 1]])
        half = (b[j][:, [3, 4]] / 2.0).T[:, :, None]
        inter = _rect_intersection_area(poly, half) * dy[i, j]
        out[i, j] = np.clip(inter / (vol_a[i] + vol_b[j] - inter), 0.0, 1.0)
    return out


def boxes_from_pixel_bounds(bounds: np.ndarray) -> np.ndarray:
    """Inclusive pixel bounds ``[u_min, v_min, u_max, v_max]`` (..., 4) of pixel sets -> their 2D
    boxes (..., 4) float64 in the README convention: pixel (u, v) spans [u - 0.5, u + 0.5], so a
    box runs along the set's outer pixel edges."""
    return np.asarray(bounds, np.float64) + np.array([-0.5, -0.5, 0.5, 0.5])
