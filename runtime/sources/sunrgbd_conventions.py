"""SUN RGB-D's conventions turned into a3d's: axes, tilt, pixels, depth PNGs, boxes, class names.

Pure numpy; ``a3d.runtime.sources.sunrgbd`` reads the files. Sources: the data set's MATLAB
toolbox (SUNRGBDtoolbox: ``read3dPoints.m``, ``read_3d_pts_general.m``, ``readframeSUNRGBD.m``)
and the preparation scripts of VoteNet / mmdetection3d (``extract_rgbd_data_v2.m``,
``sunrgbd_utils.py``), which write their files from it.

Frames (each a right-handed set of axes, metres):

* ``c``, a3d's camera frame: x right, y down, z forward.
* ``d``, SUN's "depth" frame: x right, y forward, z up; ``d = A c`` with
  ``A = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]`` (VoteNet's ``flip_axis_to_depth``).
* ``u``, SUN's upright frame: ``u = Rtilt_sun d``, z up along gravity. The point clouds and the
  label boxes of the VoteNet layout are in it, and its ``calib/*.txt`` holds ``Rtilt_sun``.
* ``w``, the release's annotation frame: ``w = E c`` with ``E`` the first 3 x 3 of the
  release's ``extrinsics/*.txt``, x right, y down along gravity; the toolbox sets
  ``Rtilt_sun = A E A^T`` ("convert it into matlab coordinate"), so ``u = A w``. The
  ``annotation3Dfinal`` footprints (X, Z) and heights (Ymin, Ymax) are in it.

a3d's ``R_tilt`` (``p_tilt = R_tilt p_cam``, ``R_x(pitch) R_z(roll)``, tilt y down along gravity)
is the rotation without yaw that has E's gravity: gravity in the camera frame is ``E^T [0, 1, 0]``
(E's second row), and ``R_tilt = rtilt_from_gravity(E[1])``. E may also turn about gravity (a yaw
``E = R_y(psi) R_tilt``); boxes do not depend on it, because their corners are taken to the
camera frame and from there into a3d's tilt frame, where ``boxes_from_corners_tilt`` measures
their theta.

Pixels: the toolbox back-projects the pixel of 1-based column i and row j as
``x = (i - cx) z / fx``: SUN's principal point is in 1-based pixel coordinates, so for a3d's
0-based pixels (README "Pixels") ``cx_a3d = cx - 1``, ``cy_a3d = cy - 1`` (``intrinsics_from_sun``).
A 2D box ``[x, y, w, h]`` of the VoteNet labels is in the same 1-based image coordinates:
``[x - 1, y - 1, x + w - 1, y + h - 1]`` in a3d's.

Depth PNG: 16-bit, each value a 3-bit circular right shift of millimetres,
``mm = ((v >> 3) | (v << 13)) & 0xFFFF``; depth beyond 8 m is set to 8 m, as ``read3dPoints``
does (the toolbox's annotation and VoteNet's point clouds saw it so). 0 = missing.

Boxes (``boxes_from_footprints``, ``boxes_from_labels``): a release footprint is a rectangle
whose first three points p1, p2, p3 span it (``readframeSUNRGBD``: centre (p1 + p3) / 2, edges
p2 - p1 and p3 - p2), between heights Ymin and Ymax on w's y. A VoteNet label line
``class x y w h cx cy cz hx hy hz ox oy`` holds the centre in u, half extents (hx half the
footprint's first edge, hy half its second, hz half the height) and the unit vector (ox, oy) from
the centre to the first edge's midpoint: the box spans +-hy along (ox, oy, 0), +-hx along
(-oy, ox, 0) and +-hz along z (VoteNet's ``heading_angle = -atan2(oy, ox)`` with ``l = hy``
"along heading arrow" is the same box). Either way the 8 corners go to the camera frame, then
to a3d's tilt frame, and become a 7-vector there (l >= w, theta in a3d's tilt frame).

Classes (``map_class``): a SUN name is normalised like NYUv2's (``night_stand`` -> night stand,
``garbage_bin`` -> garbage bin, ``tv`` -> television; the release's ``"name:label"`` suffix cut as
the toolbox cuts it); ``nyu19`` keeps the paper's 19 classes, ``sun10`` the 10 of the SUN RGB-D
benchmark (bed, table, sofa, chair, toilet, desk, dresser, night stand, bookshelf, bathtub).
Other names (``sofa_chair``, ``coffee_table``, ...) are not annotations of a3d's classes and are
dropped, as VoteNet drops them.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.protocols import SUNRGBD_CLASSES
from a3d.runtime.frontend.gravity import rtilt_from_gravity
from a3d.runtime.sources.arrays import MILLIMETRE, depth_units_to_metres
from a3d.runtime.structures.classes import CLASSES, normalize_class_name
from a3d.runtime.structures.geometry import Intrinsics, boxes_from_corners_tilt

A = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""SUN's depth frame from a3d's camera frame: ``d = A c``."""
MAX_DEPTH_M = 8.0
CLASS_SETS: dict[str, tuple[str, ...]] = {"nyu19": CLASSES, "sun10": SUNRGBD_CLASSES}
_FOOTPRINT_SIGNS = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)


def decode_depth_png(values: np.ndarray) -> np.ndarray:
    """float32 metres (0 = missing, at most 8 m) of a SUN depth PNG's uint16 values."""
    v = np.asarray(values, dtype=np.uint16)
    millimetres = (v >> 3) | (v << 13)  # uint16 arithmetic: the bits shifted out are dropped (& 0xFFFF)
    return np.minimum(depth_units_to_metres(millimetres, MILLIMETRE), np.float32(MAX_DEPTH_M))


def intrinsics_from_sun(K: np.ndarray) -> Intrinsics:
    """a3d's intrinsics (0-based pixels) of a SUN camera matrix (1-based pixels)."""
    K = np.asarray(K, dtype=np.float64)
    return Intrinsics(K[0, 0], K[1, 1], K[0, 2] - 1.0, K[1, 2] - 1.0)


def boxes2d_from_sun(boxes: np.ndarray) -> np.ndarray:
    """SUN ``[x, y, w, h]`` (1-based image coordinates) -> a3d ``[x1, y1, x2, y2]``."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return np.column_stack([b[:, 0] - 1, b[:, 1] - 1, b[:, 0] + b[:, 2] - 1, b[:, 1] + b[:, 3] - 1])


def nearest_rotation(R: np.ndarray, what: str, tol: float = 1e-2) -> np.ndarray:
    """The rotation nearest to R (files hold it to a few digits); InputError if R is far from one."""
    M = np.asarray(R, dtype=np.float64)
    if M.shape != (3, 3) or not np.isfinite(M).all():
        raise InputError(f"{what}: expected a finite 3x3 rotation, got shape {M.shape}")
    U, _, Vt = np.linalg.svd(M)
    nearest = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    error = float(np.max(np.abs(nearest - M)))
    if error > tol or np.linalg.det(M) <= 0:
        raise InputError(f"{what}: not a rotation (entries {error:.3g} from the nearest one)")
    return nearest


def annotation_from_upright(Rtilt_sun: np.ndarray) -> np.ndarray:
    """E (``w = E c``) of a toolbox / VoteNet ``Rtilt_sun`` (``Rtilt_sun = A E A^T``)."""
    return A.T @ Rtilt_sun @ A


def rtilt_from_annotation(E: np.ndarray) -> np.ndarray:
    """a3d's R_tilt of the annotation rotation E: the same gravity, no yaw."""
    return rtilt_from_gravity(np.asarray(E, dtype=np.float64)[1])


def _boxes(corners_camera: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    return boxes_from_corners_tilt(corners_camera @ R_tilt.T, R_tilt)


def boxes_from_footprints(footprints: np.ndarray, heights: np.ndarray, E: np.ndarray, R_tilt: np.ndarray):
    """7-vectors (N, 7) of release boxes: ``footprints`` (N, 3, 2) the points p1, p2, p3 as (X, Z),
    ``heights`` (N, 2) (Ymin, Ymax), all in the annotation frame ``w = E c``."""
    p = np.asarray(footprints, dtype=np.float64).reshape(-1, 3, 2)
    h = np.asarray(heights, dtype=np.float64).reshape(-1, 2)
    centre = (p[:, 0] + p[:, 2]) / 2
    half_a, half_b = (p[:, 1] - p[:, 0]) / 2, (p[:, 2] - p[:, 1]) / 2
    xz = (
        centre[:, None]
        + _FOOTPRINT_SIGNS[None, :, :1] * half_a[:, None]
        + _FOOTPRINT_SIGNS[None, :, 1:] * half_b[:, None]
    )
    ys = np.sort(h, axis=1)
    corners_w = np.concatenate(
        [np.stack([xz[..., 0], np.repeat(ys[:, i : i + 1], 4, axis=1), xz[..., 1]], axis=-1) for i in (1, 0)],
        axis=1,
    )
    return _boxes(corners_w @ np.asarray(E, dtype=np.float64), R_tilt)  # c = E^T w, as rows


def boxes_from_labels(
    centres: np.ndarray, halves: np.ndarray, headings: np.ndarray, Rtilt_sun: np.ndarray, R_tilt: np.ndarray
) -> np.ndarray:
    """7-vectors (N, 7) of VoteNet label boxes: ``centres`` (N, 3), ``halves`` (N, 3) = (hx, hy, hz)
    and ``headings`` (N, 2) = (ox, oy), in the upright frame ``u = Rtilt_sun A c``."""
    centre = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    half = np.abs(np.asarray(halves, dtype=np.float64).reshape(-1, 3))
    o = np.asarray(headings, dtype=np.float64).reshape(-1, 2)
    norm = np.linalg.norm(o, axis=1, keepdims=True)
    if np.any(norm == 0):
        raise InputError("label: a box has heading vector (0, 0)")
    o = o / norm
    along = np.column_stack([o, np.zeros(len(o))]) * half[:, 1:2]
    across = np.column_stack([-o[:, 1], o[:, 0], np.zeros(len(o))]) * half[:, 0:1]
    up = np.zeros_like(centre)
    up[:, 2] = half[:, 2]
    footprint = (
        centre[:, None]
        + _FOOTPRINT_SIGNS[None, :, :1] * along[:, None]
        + _FOOTPRINT_SIGNS[None, :, 1:] * across[:, None]
    )
    corners_u = np.concatenate([footprint - up[:, None], footprint + up[:, None]], axis=1)
    return _boxes(corners_u @ np.asarray(Rtilt_sun, dtype=np.float64) @ A, R_tilt)  # c = A^T Rtilt^T u


def depth_from_points(
    points_u: np.ndarray, Rtilt_sun: np.ndarray, K: Intrinsics, size: tuple[int, int]
) -> np.ndarray:
    """float32 depth (H, W) of upright-frame points (N, >= 3): each point to its nearest pixel,
    the nearest surface winning where several land on one; pixels without a point are 0."""
    camera = np.asarray(points_u, dtype=np.float64)[:, :3] @ np.asarray(Rtilt_sun, dtype=np.float64) @ A
    camera = camera[np.isfinite(camera).all(axis=1) & (camera[:, 2] > 0)]
    z = camera[:, 2]
    u = np.rint(K.fx * camera[:, 0] / z + K.cx)
    v = np.rint(K.fy * camera[:, 1] / z + K.cy)
    H, W = size
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    nearest = np.full(H * W, np.inf)
    np.minimum.at(nearest, v[inside].astype(np.int64) * W + u[inside].astype(np.int64), z[inside])
    nearest[np.isinf(nearest)] = 0.0
    return nearest.reshape(H, W).astype(np.float32)


def map_class(name: str, classes: str) -> str | None:
    """The a3d class of a SUN object name under ``classes`` ("nyu19" or "sun10"), or None."""
    base = name.split(":", 1)[0].rstrip("_ ")
    cls = normalize_class_name(base)
    return cls if cls is not None and cls in CLASS_SETS[classes] else None
