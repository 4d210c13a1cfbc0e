"""One synthetic RGB-D frame with amodal ground truth: ``generate_frame(seed, config)``.

Pipeline: furnish a random room (``rooms``, plus objects of no class with ``world``), choose a
handheld camera pose that sees many objects (``camera``), ray-cast the exact depth and the
visible part of every pixel (``raycast``), shade it (``shading``, plus daylight with ``photo``),
then apply the sensor models (``sensor``, ``depth_families``, ``photo``).

Ground truth, per object of one of the 19 classes with at least ``min_visible_px`` visible
pixels (smaller ones are rendered but not annotated, and are 0 in the instance map):

* ``box3d``: the tight box of all the object's parts in its own yaw-aligned frame (also where it
  is occluded or outside the image), as the README 7-vector (camera-frame centre, l >= w,
  theta = tilt-frame yaw in [-pi/2, pi/2]);
* ``box2d_visible``: the exact pixel extent of its visible pixels (README pixel convention);
* ``box2d_amodal``: ``geometry.project_boxes_to_2d`` of box3d;
* its visible-instance mask in ``instances`` (1..N in annotation order).

Visibility (``ObjectRecord.visibility``) = visible pixels / pixels of the object's own
unoccluded projection on an unbounded image plane: the object rendered alone (no other object,
no room) in the image, plus its area outside the image estimated on a 4-pixel grid over a canvas
twice the image's size (objects straddling the camera plane are cut at that canvas). An object
is *cut by the image border* (``truncated``) when more than 2% of that projection is outside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from a3d.runtime.structures.boxes import boxes_array
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import (
    NYU_CROP_INTRINSICS,
    NYU_CROP_SIZE,
    Intrinsics,
    boxes_from_pixel_bounds,
    canonical_boxes,
    project_boxes_to_2d,
)
from a3d.synth import appearance, photo, shading
from a3d.synth.camera import CameraPose, CameraRanges, choose_camera
from a3d.synth.depth_families import sense
from a3d.synth.layout import Placed
from a3d.synth.parts import N_SLOTS
from a3d.synth.raycast import PartArrays, RayGrid, cast, room_exit
from a3d.synth.sensor import DepthSensor, sense_colour
from a3d.synth.world import furnish_world

APPEARANCES = ("independent", "typical")
PER_FAMILY = 2  # with "typical" appearance: materials of each family drawn per frame
OUTSIDE_STRIDE = 4  # pixels between samples of an object's projection outside the image
TRUNCATED_FRACTION = 0.02  # share of the projection outside the image that makes an object "cut"


@dataclass(frozen=True)
class SceneConfig:
    """What to render: image size (H, W) and intrinsics, camera pose ranges, annotation threshold,
    sensor models (``noise`` False gives exact depth and noise-free colour), room type (None: random),
    and whether materials are drawn independently of the class or class-typical. The cluttered
    world (``a3d.synth.world``, ``a3d.synth.photo``): ``clutter`` objects of no class added per
    room, ``labelled`` False for rooms without class objects, ``real_light`` for daylight,
    glowing windows and a consumer camera's colour pipeline; ``device`` names the camera preset
    (``a3d.synth.devices``) that set the size, intrinsics and depth sensor, for the statistics."""

    image_size: tuple[int, int] = NYU_CROP_SIZE
    intrinsics: Intrinsics = NYU_CROP_INTRINSICS
    camera: CameraRanges = field(default_factory=CameraRanges)
    min_visible_px: int = 50
    noise: bool = True
    depth_sensor: DepthSensor = field(default_factory=DepthSensor)
    palette: int = 12  # object materials drawn per frame
    room_type: str | None = None
    appearance: str = "independent"  # or "typical": class-typical materials (a3d.synth.appearance)
    typical_share: float = 0.7  # with "typical": the share of models in class-typical materials
    clutter: int = 0
    labelled: bool = True
    real_light: bool = False
    device: str = ""

    def __post_init__(self) -> None:
        if self.appearance not in APPEARANCES:
            raise ValueError(f"SceneConfig: appearance must be one of {APPEARANCES}, not {self.appearance!r}")
        if not 0.0 <= self.typical_share <= 1.0:
            raise ValueError(f"SceneConfig: typical_share must lie in [0, 1], not {self.typical_share}")
        if self.clutter < 0:
            raise ValueError(f"SceneConfig: clutter must be >= 0, not {self.clutter}")


@dataclass(frozen=True)
class ObjectRecord:
    """Statistics of one rendered object of a class that is at least partly in the image
    (annotated or not); ``SynthFrame.objects`` lists the annotated ones in ground-truth order."""

    cls: str
    annotated: bool
    visible_px: int
    alone_px: int  # unoccluded, inside the image
    full_px: float  # unoccluded, on the unbounded image plane (estimated outside the image)
    visibility: float
    truncated: bool


@dataclass(frozen=True)
class SynthFrame:
    """A rendered frame: ``color`` (H, W, 3) uint8 BGR, ``depth`` (H, W) float32 metres (0 =
    missing, sensor-like), ``depth_exact`` the noise-free z-depth, ``R_tilt`` (3, 3), intrinsics,
    ground truth, ``instances`` (H, W) uint16, ``floor`` (H, W) bool (visible floor pixels),
    per-object statistics, room type and camera pose; ``unlabelled``: objects of no class with at
    least ``min_visible_px`` visible pixels; ``device``: the camera preset's name ("" none)."""

    color: np.ndarray
    depth: np.ndarray
    depth_exact: np.ndarray
    R_tilt: np.ndarray
    intrinsics: Intrinsics
    gt: GroundTruth
    instances: np.ndarray
    floor: np.ndarray
    objects: list[ObjectRecord]
    room_type: str
    camera: CameraPose
    unlabelled: int
    device: str


def generate_frame(
    seed: int,
    config: SceneConfig = SceneConfig(),
    camera: CameraPose | None = None,
    noise_seed: int | None = None,
) -> SynthFrame:
    """Render the frame of ``seed`` (the same seed always gives the same frame).

    ``camera`` views the room of ``seed`` from that pose instead of the chosen one (a3d.synth.sequence:
    one room, many views): the room, its materials and its lights stay those of ``seed`` (the lights
    are drawn for the chosen pose and moved into this one), and ``noise_seed`` draws the sensor's
    noise, so that every view has its own."""
    rng = np.random.default_rng(seed)
    H, W = config.image_size
    kind, layout = furnish_world(rng, config.room_type, config.clutter, config.labelled)
    chosen = choose_camera(layout, rng, config.camera, config.intrinsics, config.image_size)
    pose = chosen if camera is None else camera
    R = pose.R_tilt
    K = config.intrinsics.matrix()
    placed = [p for p in layout.objects if p.render]
    parts, mats, room_faces = build_parts(placed, pose, rng, config)
    n_obj, n_parts = len(placed), len(parts)

    grid = RayGrid.make(np.zeros(3), R, K, (H, W))
    room = layout.room
    room_centre = pose.room_to_tilt(
        np.array(room.width / 2), np.array(room.height / 2), np.array(room.depth / 2)
    )
    room_half = np.array([room.width / 2, room.height / 2, room.depth / 2])
    render = cast(grid, parts, n_obj, t=room_exit(grid, room_half, room_centre, -pose.heading))
    part = np.where(render.part >= 0, render.part, n_parts)  # index n_parts = the room
    t = render.t
    obj_map = np.append(parts.obj, -1)[part]
    visible = np.bincount(obj_map[obj_map >= 0], minlength=n_obj)

    outside = _outside_counts(grid, parts, n_obj, render.alone, (H, W))
    full = render.alone + outside
    records, gt, instances = _ground_truth(placed, pose, visible, render.alone, full, obj_map, config)

    all_parts = _with_room(parts, room_centre, room_half, -pose.heading)
    surf = shading.surfaces(grid, t, part, all_parts)
    ray = grid.d / np.linalg.norm(grid.d, axis=0, keepdims=True)
    cos_inc = np.sum(surf.normal * ray, axis=0)
    footprint = t * np.linalg.norm(grid.d, axis=0) / (config.intrinsics.fx * np.maximum(np.abs(cos_inc), 0.2))
    alb = shading.albedo(surf, part, all_parts, mats, room_faces, footprint)
    gloss = np.where(surf.face >= 0, 0.0, mats.gloss[all_parts.material[part]]).astype(np.float32)
    corners = _room_corners(pose, room.width, room.depth)
    drawn_in = _room_corners(chosen, room.width, room.depth)  # lights are drawn about the chosen pose
    lights = shading.draw_lights(rng, chosen.height - room.height, drawn_in)
    if config.real_light:
        windows = [p.yaw - chosen.heading for p in placed if p.item.glow >= 0]
        lights = photo.add_daylight(rng, lights, float(rng.choice(windows)) if windows else None)
    if camera is not None:
        lights = _moved_lights(lights, chosen, pose)
    if noise_seed is not None:
        rng = np.random.default_rng(noise_seed)
    lit_sun = None
    if config.real_light:
        if lights.sun_dir is not None:
            centre = np.array([corners[:, 0].mean(), pose.height - room.height / 2, corners[:, 2].mean()])
            radius = 0.5 * math.sqrt(room.width**2 + room.depth**2 + room.height**2) + 0.1
            lit_sun = shading.sun_shadow(surf.point, lights.sun_dir, parts, n_obj, centre, radius)
    lit = shading.shadow_factor(surf.point, lights.positions[0], parts, n_obj)
    radiance = shading.illuminate(surf, alb, gloss, lights, t, lit, lit_sun)
    if config.real_light:
        radiance = photo.glow(rng, radiance, np.isin(part, _glowing_parts(placed, parts)))

    lum = 0.2126 * alb[..., 0] + 0.7152 * alb[..., 1] + 0.0722 * alb[..., 2]
    if config.noise:
        color = photo.sense_colour_real(rng, radiance) if config.real_light else sense_colour(rng, radiance)
        depth = sense(rng, t, config.intrinsics.fx, lum, cos_inc, config.depth_sensor)
    else:
        img = np.clip(radiance * (0.7 / max(float(np.percentile(radiance, 95)), 1e-4)), 0, 1) ** (1 / 2.2)
        color = np.ascontiguousarray((img[..., ::-1] * 255 + 0.5).astype(np.uint8))
        depth = t.astype(np.float32).copy()
    return SynthFrame(
        color,
        depth,
        t.astype(np.float32),
        R,
        config.intrinsics,
        gt,
        instances,
        surf.face == shading.FLOOR,
        records,
        kind,
        pose,
        int(
            sum(
                p.item.cls is None and v >= config.min_visible_px
                for p, v in zip(placed, visible, strict=True)
            )
        ),
        config.device,
    )


def _room_corners(pose: CameraPose, width: float, depth: float) -> np.ndarray:
    """The room's four floor corners (4, 3) in the tilt frame of ``pose``."""
    return pose.room_to_tilt(np.array([0, width, width, 0.0]), np.zeros(4), np.array([0, 0, depth, depth]))


def _moved_lights(lights: shading.Lights, old: CameraPose, new: CameraPose) -> shading.Lights:
    """Lights given in the tilt frame of pose ``old``, in that of pose ``new`` (the same room lights)."""
    room = old.tilt_to_room(lights.positions)
    positions = new.room_to_tilt(room[:, 0], room[:, 1], room[:, 2])
    sun_dir = None
    if lights.sun_dir is not None:  # a direction turns with the heading only
        ends = old.tilt_to_room(np.stack([np.zeros(3), lights.sun_dir]))
        moved = new.room_to_tilt(ends[:, 0], ends[:, 1], ends[:, 2])
        sun_dir = moved[1] - moved[0]
    return shading.Lights(lights.ambient, positions, lights.powers, sun_dir, lights.sun)


def _glowing_parts(placed: list[Placed], parts: PartArrays) -> np.ndarray:
    """Indices of the light-emitting parts (``Furniture.glow``) among the rendered parts."""
    first = np.searchsorted(parts.obj, np.arange(len(placed)))  # parts are grouped by object, in order
    return np.array([first[i] + p.item.glow for i, p in enumerate(placed) if p.item.glow >= 0], np.int64)


def build_parts(
    placed: list[Placed], pose: CameraPose, rng: np.random.Generator, config: SceneConfig
) -> tuple[PartArrays, shading.Materials, np.ndarray]:
    """All rendered parts in the tilt frame, the materials (object palette, then floor, wall and
    ceiling, then with "typical" appearance the family materials) and the room's material per
    surface (indexed FLOOR, CEILING, WALL).

    Every distinct furniture model picks N_SLOTS materials uniformly from the palette, whatever
    its class (pieces placed several times, like a set of chairs, share theirs); with "typical"
    appearance some then take class-typical ones (``appearance.typical_slots``).
    """
    palette, typical = config.palette, config.appearance == "typical"
    banks = [
        shading.draw_materials(rng, palette),
        shading.draw_materials(rng, 1, "floor"),
        shading.draw_materials(rng, 1, "wall"),
        shading.draw_materials(rng, 1, "ceiling"),
    ]
    first_family = sum(len(bank.tile) for bank in banks)  # the family materials follow the room's
    if typical:
        banks.append(appearance.draw_family_materials(rng, PER_FAMILY))
    mats = shading.concat_materials(*banks)
    room_faces = palette + np.array([0, 2, 1])  # floor, wall, ceiling materials follow the palette
    slots: dict[int, np.ndarray] = {}
    kind, centre, half, yaw, obj, material = [], [], [], [], [], []
    for i, p in enumerate(placed):
        key = id(p.item)
        if key not in slots:
            slots[key] = rng.integers(0, palette, N_SLOTS)
            if typical:
                slots[key] = appearance.typical_slots(
                    rng, p.item.cls, slots[key], first_family, PER_FAMILY, config.typical_share
                )
        for q in p.item.parts:
            x, z = p.to_room(q.centre[0], q.centre[2])
            centre.append((x, p.base + q.centre[1], z))
            kind.append(q.kind)
            half.append(q.half)
            yaw.append(p.yaw + q.yaw - pose.heading)
            obj.append(i)
            material.append(slots[key][q.slot])
    c = np.array(centre, np.float64).reshape(-1, 3)
    tilt = pose.room_to_tilt(c[:, 0], c[:, 1], c[:, 2])
    n = len(kind)
    parts = PartArrays(
        np.array(kind, np.int64),
        tilt,
        np.array(half, np.float64).reshape(-1, 3),
        np.array(yaw, np.float64),
        np.array(obj, np.int64),
        np.array(material, np.int64),
        shading.tint_jitter(rng, n),
    )
    return parts, mats, room_faces


def _with_room(parts: PartArrays, centre: np.ndarray, half: np.ndarray, yaw: float) -> PartArrays:
    """The parts plus the room box as the last part (kind ROOM)."""
    return PartArrays(
        np.append(parts.kind, shading.ROOM),
        np.vstack([parts.centre, centre]),
        np.vstack([parts.half, half]),
        np.append(parts.yaw, yaw),
        np.append(parts.obj, -1),
        np.append(parts.material, 0),
        np.vstack([parts.tint, np.ones((1, 3))]),
    )


def _outside_counts(
    grid: RayGrid, parts: PartArrays, n_obj: int, alone: np.ndarray, size: tuple[int, int]
) -> np.ndarray:
    """Estimated pixel area of each object's unoccluded projection outside the image."""
    H, W = size
    rects = grid.rects(parts)
    touches = (rects[:, 1] > rects[:, 0]) & (rects[:, 3] > rects[:, 2])
    touches &= (rects[:, 0] == 0) | (rects[:, 1] == H) | (rects[:, 2] == 0) | (rects[:, 3] == W)
    behind = ~((rects[:, 1] > rects[:, 0]) & (rects[:, 3] > rects[:, 2]))  # parts wholly outside the image
    cut = np.unique(parts.obj[touches | behind])
    cut = cut[alone[cut] > 0]  # objects wholly outside the image are not in the frame at all
    if len(cut) == 0:
        return np.zeros(n_obj)
    s = OUTSIDE_STRIDE
    ext = RayGrid.make(
        grid.origin, grid.rot, grid.K, (math.ceil(2 * H / s), math.ceil(2 * W / s)), -W / 2, -H / 2, s
    )
    return cast(ext, parts, n_obj, objects=cut, count_outside=size).alone * float(s * s)


def _ground_truth(
    placed: list[Placed],
    pose: CameraPose,
    visible: np.ndarray,
    alone: np.ndarray,
    full: np.ndarray,
    obj_map: np.ndarray,
    config: SceneConfig,
) -> tuple[list[ObjectRecord], GroundTruth, np.ndarray]:
    H, W = config.image_size
    records, names, boxes, vis_boxes, keep = [], [], [], [], []
    for i, p in enumerate(placed):
        cls = p.item.cls
        if cls is None or alone[i] <= 0:  # not a class, or not in the image
            continue
        annotated = bool(visible[i] >= config.min_visible_px)
        visibility = float(visible[i] / full[i])
        records.append(
            ObjectRecord(
                cls,
                annotated,
                int(visible[i]),
                int(alone[i]),
                float(full[i]),
                visibility,
                bool(full[i] - alone[i] > TRUNCATED_FRACTION * full[i]),
            )
        )
        if not annotated:
            continue
        lo, hi = p.item.lo, p.item.hi
        cx, cz = p.to_room(0.5 * (lo[0] + hi[0]), 0.5 * (lo[2] + hi[2]))
        c_tilt = pose.room_to_tilt(np.array(cx), np.array(p.base + 0.5 * (lo[1] + hi[1])), np.array(cz))
        size = hi - lo
        boxes.append([*(pose.R_tilt.T @ c_tilt), size[0], size[2], size[1], p.yaw - pose.heading])
        rows, cols = np.nonzero(obj_map == i)
        vis_boxes.append(boxes_from_pixel_bounds([cols.min(), rows.min(), cols.max(), rows.max()]))
        names.append(cls)
        keep.append(i)
    n = len(names)
    boxes3d = canonical_boxes(boxes_array(boxes, n))
    amodal = project_boxes_to_2d(boxes3d, pose.R_tilt, config.intrinsics, (H, W))
    ids = np.arange(1, n + 1)
    lut = np.zeros(len(placed) + 1, np.uint16)
    lut[np.array(keep, np.int64)] = ids
    instances = lut[obj_map]  # obj_map -1 (room) reads the last entry, 0
    gt = GroundTruth.from_classes(names, boxes3d, np.array(vis_boxes).reshape(n, 4), amodal, ids)
    return records, gt, instances
