"""The object map: a posed recording's detections fused into one box per object in the world.

    from a3d.runtime.mapping.object_map import ObjectMap
    world_map = ObjectMap()
    for result, frame in ...:                      # a3d-run --map does this for every frame
        world_map.update(result, frame.pose, intrinsics=frame.intrinsics, depth=frame.depth)
    world_map.objects                              # MapObject: class, fused box, support, score, ...
    world_map.write("map.json")                   # atomically; world_map.to_json() is its text

Per frame (docs/mapping.md "The object map"): the detections scoring at least ``min_score`` are
moved into the map's frame (a3d.runtime.mapping.world), associated to the map's objects
(a3d.runtime.mapping.association: same class, centre and 3D IoU gates) and each matched object's
box is refitted from all its observations (a3d.runtime.mapping.fusion: robust, score-weighted,
yaw modulo pi with the l/w symmetry); a detection that matches nothing starts a new object.
An object the frame should have seen (its centre in the image, in range, not behind a nearer
surface of the depth map) but did not is *missed*. An object is *confirmed* once ``min_support``
frames saw it; one that is not and is missed ``max_misses`` times is dropped (a spurious
detection, seen once and never again where it should have been). Its fused score is the mean
score of its detections times the share of the frames that should have seen it that did.
Two objects of one class whose boxes come to overlap (3D IoU >= ``merge_iou``) are merged.

The map's frame: the poses' world turned so that its y axis is gravity (down). The down direction
is taken from the first mapped frame (its pose and its ``R_tilt``, given or estimated); for an
a3d-synth sequence, whose world is gravity-aligned, the turn is the identity. Frames whose gravity
is a fallback (a3d.runtime.frontend.gravity) are not mapped: their boxes' up is a guess. The
scene is assumed static: an object that moves becomes a second object, and the first one's
fused score decays as it is missed.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.io.image_io import read_bytes
from a3d.runtime.io.json_input import parse_json
from a3d.runtime.mapping.association import AssociationGates, associate
from a3d.runtime.mapping.fusion import fuse_boxes
from a3d.runtime.mapping.world import boxes_to_camera, boxes_to_world
from a3d.runtime.structures.boxes import CENTER, SIZE, THETA
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import Intrinsics, box_area_2d, iou_3d, project_boxes_to_2d
from a3d.runtime.structures.pose import make_pose, rotation_deg

MAP_VERSION = 1
MAP_TURN_DEG = 3.0  # a map whose frame is turned further from its recording's world does not share it
FALLBACK = "fallback"


@dataclass(frozen=True)
class MapConfig:
    """The map's settings (module docstring): ``min_score`` of a detection to be mapped (the
    calibrated scores' 0.5: as likely right as wrong); association ``gates``; ``min_support``
    frames to confirm an object, ``max_misses`` to drop an unconfirmed one; an object is expected
    in a frame when its centre is 0.3 to ``max_range_m`` m ahead and ``image_margin`` (a share of
    the image size) inside the image's border; ``merge_iou``: objects of one class overlapping this
    much are one."""

    min_score: float = 0.5
    gates: AssociationGates = field(default_factory=AssociationGates)
    min_support: int = 2
    max_misses: int = 3
    max_range_m: float = 6.0
    image_margin: float = 0.1
    merge_iou: float = 0.3


@dataclass
class MapObject:
    """One object of the map: its class, fused ``box`` (7,) in the map's frame, and every
    observation that supports it (map-frame boxes, scores, frame names and indices)."""

    id: int
    class_id: int
    box: np.ndarray
    observations: list[np.ndarray]
    scores: list[float]
    frames: list[str]
    frame_indices: list[int]
    misses: int = 0

    @property
    def cls(self) -> str:
        return CLASSES[self.class_id]

    @property
    def support(self) -> int:
        """Frames that detected it (two merged detections of one frame count once)."""
        return len(set(self.frames))

    def score(self) -> float:
        """Mean detection score times the share of the frames expected to see it that did."""
        return float(np.mean(self.scores)) * self.support / (self.support + self.misses)

    def refit(self) -> None:
        self.box = fuse_boxes(np.array(self.observations), np.array(self.scores))

    def to_dict(self, min_support: int) -> dict:
        return {
            "id": self.id,
            "class": self.cls,
            "centre": _rounded(self.box[CENTER]),
            "size": _rounded(self.box[SIZE]),
            "yaw": round(float(self.box[THETA]), 6),
            "score": round(self.score(), 6),
            "confirmed": self.support >= min_support,
            "support": self.support,
            "misses": self.misses,
            "first_seen": self.frames[0],
            "last_seen": self.frames[-1],
            "frames": self.frames,
        }


@dataclass(frozen=True)
class MapUpdate:
    """What one ``update`` did: ``skipped`` (why the frame was not mapped, "" if it was), objects
    ``matched``, ``created``, ``missed``, ``dropped`` and ``merged`` (ids)."""

    skipped: str = ""
    matched: tuple[int, ...] = ()
    created: tuple[int, ...] = ()
    missed: tuple[int, ...] = ()
    dropped: tuple[int, ...] = ()
    merged: tuple[int, ...] = ()


class ObjectMap:
    """The object map of one posed recording (module docstring)."""

    def __init__(self, config: MapConfig = MapConfig()) -> None:
        self.config = config
        self.alignment: np.ndarray | None = None  # (4, 4): the poses' world -> the map's frame
        self.world_down: np.ndarray | None = None  # gravity in the poses' world, from the first frame
        self.frames_mapped = 0
        self.frames_skipped: Counter[str] = Counter()
        self.dropped: list[MapObject] = []  # for the statistics: spurious objects
        self._objects: list[MapObject] = []
        self._next_id = 0
        self._down_angles: list[float] = []
        self.trajectory: list[np.ndarray] = []  # the mapped frames' camera positions, in the map's frame
        self.camera: np.ndarray | None = None  # the last mapped frame's camera-to-map pose (4, 4)

    @property
    def objects(self) -> list[MapObject]:
        """The current objects, confirmed or not, in the order they were first seen."""
        return list(self._objects)

    def confirmed(self) -> list[MapObject]:
        return [o for o in self._objects if o.support >= self.config.min_support]

    def update(
        self,
        result: FrameDetections,
        pose: np.ndarray | None = None,
        *,
        intrinsics: Intrinsics | None = None,
        depth: np.ndarray | None = None,
        image_size: tuple[int, int] | None = None,
    ) -> MapUpdate:
        """Add one frame's detections (``pose``: its camera-to-world pose, else ``result.pose``).

        ``intrinsics`` and the image size (``image_size`` or ``depth``'s) let the map tell which
        objects the frame should have seen (misses); ``depth`` (H, W) metres also lets it tell
        which of those were hidden behind something nearer. Without them nothing is missed."""
        pose = result.pose if pose is None else pose
        if pose is None:
            return self._skip("no pose")
        if (result.gravity or "").startswith(FALLBACK):
            return self._skip("gravity fallback")
        R_tilt = np.asarray(result.R_tilt, np.float64)
        down = pose[:3, :3] @ R_tilt[1]  # R_tilt's second row: gravity in the camera frame
        if self.alignment is None:
            self.world_down = down
            self.alignment = make_pose(_turn_to_y(down), np.zeros(3))
        self._down_angles.append(float(np.degrees(np.arccos(np.clip(down @ self.world_down, -1.0, 1.0)))))
        map_pose = self.alignment @ pose
        self.camera = map_pose
        self.trajectory.append(map_pose[:3, 3].copy())
        frame_index = self.frames_mapped
        self.frames_mapped += 1

        keep = np.flatnonzero(np.asarray(result.scores) >= self.config.min_score)
        boxes = boxes_to_world(result.boxes3d[keep], R_tilt, map_pose)
        classes = np.asarray(result.class_ids)[keep]
        existing = list(self._objects)
        obj_boxes = np.array([o.box for o in existing]).reshape(-1, 7)
        obj_classes = np.array([o.class_id for o in existing], np.int64)
        pairs = associate(boxes, classes, obj_boxes, obj_classes, self.config.gates)
        matched_det = {i for i, _ in pairs}
        for i, j in pairs:
            obj = existing[j]
            obj.observations.append(boxes[i])
            obj.scores.append(float(result.scores[keep[i]]))
            obj.frames.append(result.frame)
            obj.frame_indices.append(frame_index)
            obj.refit()
        created = []
        for i in range(len(boxes)):
            if i not in matched_det:
                created.append(
                    self._new_object(
                        int(classes[i]), boxes[i], float(result.scores[keep[i]]), result.frame, frame_index
                    )
                )
        missed, dropped = [], []
        size = image_size if image_size is not None else (None if depth is None else depth.shape[:2])
        if intrinsics is not None and size is not None:
            seen = {j for _, j in pairs}
            for j, obj in enumerate(existing):
                if j in seen or not self._expected(obj, map_pose, R_tilt, intrinsics, size, depth):
                    continue
                obj.misses += 1
                missed.append(obj.id)
                if obj.support < self.config.min_support and obj.misses >= self.config.max_misses:
                    self._objects.remove(obj)
                    self.dropped.append(obj)
                    dropped.append(obj.id)
        merged = self._merge()
        return MapUpdate(
            "", tuple(existing[j].id for _, j in pairs), tuple(created), tuple(missed), tuple(dropped), merged
        )

    def seen_from(
        self, result: FrameDetections, K: Intrinsics, image_size: tuple[int, int]
    ) -> FrameDetections:
        """The confirmed objects as that frame's detections (the frame's pose and gravity, from
        ``result``): each fused box moved into its camera, scored with its fused score, its 2D box
        the projected box clipped to the image; objects behind the camera or outside the image are
        left out. This is the map "projected back", to score against per-frame ground truth."""
        if self.alignment is None or result.pose is None:
            raise ValueError(f"{result.frame}: the map has no frame yet, or this frame has no pose")
        R_tilt = np.asarray(result.R_tilt, np.float64)
        objects = self.confirmed()
        world = np.array([o.box for o in objects]).reshape(-1, 7)
        boxes = boxes_to_camera(world, self.alignment @ result.pose, R_tilt)
        boxes2d = project_boxes_to_2d(boxes, R_tilt, K, image_size)
        keep = (boxes[:, 2] > 0.3) & (box_area_2d(boxes2d) > 0)
        return replace(
            result,
            class_ids=np.array([o.class_id for o in objects], np.int64).reshape(-1)[keep],
            scores=np.array([o.score() for o in objects], np.float64).reshape(-1)[keep],
            boxes2d=boxes2d[keep],
            boxes3d=boxes[keep],
            corners=None,
            boxes2d_amodal=None,
        )

    def _skip(self, why: str) -> MapUpdate:
        self.frames_skipped[why] += 1
        return MapUpdate(skipped=why)

    def _new_object(self, class_id: int, box: np.ndarray, score: float, frame: str, index: int) -> int:
        obj = MapObject(self._next_id, class_id, box.copy(), [box], [score], [frame], [index])
        obj.refit()
        self._objects.append(obj)
        self._next_id += 1
        return obj.id

    def _expected(
        self,
        obj: MapObject,
        map_pose: np.ndarray,
        R_tilt: np.ndarray,
        K: Intrinsics,
        size: tuple[int, int],
        depth: np.ndarray | None,
    ) -> bool:
        """Whether the frame should have seen ``obj``: its centre ahead within range, inside the
        image by the margin, and (with depth) not behind a nearer surface there."""
        box = boxes_to_camera(obj.box[None], map_pose, R_tilt)[0]
        x, y, z = box[CENTER]
        if not 0.3 <= z <= self.config.max_range_m:
            return False
        u, v = K.fx * x / z + K.cx, K.fy * y / z + K.cy
        H, W = size
        m = self.config.image_margin
        if not (m * W <= u <= (1 - m) * W and m * H <= v <= (1 - m) * H):
            return False
        if depth is None:
            return True
        r, c = int(np.rint(v)), int(np.rint(u))
        window = depth[max(r - 2, 0) : r + 3, max(c - 2, 0) : c + 3]
        valid = window[window > 0]
        nearest_face = z - 0.5 * max(box[3], box[4]) - 0.15
        return not (valid.size and float(np.median(valid)) < nearest_face)

    def _merge(self) -> tuple[int, ...]:
        """Merge objects of one class whose fused boxes overlap by ``merge_iou`` (the one with
        more support keeps its id); the ids merged away."""
        merged: list[int] = []
        again = True
        while again and len(self._objects) > 1:
            again = False
            boxes = np.array([o.box for o in self._objects])
            iou = iou_3d(boxes, boxes, np.eye(3))
            np.fill_diagonal(iou, 0.0)
            classes = np.array([o.class_id for o in self._objects])
            iou[classes[:, None] != classes[None, :]] = 0.0
            i, j = np.unravel_index(int(np.argmax(iou)), iou.shape)
            if iou[i, j] < self.config.merge_iou:
                break
            keep, gone = sorted((self._objects[i], self._objects[j]), key=lambda o: (-o.support, o.id))
            order = np.argsort(keep.frame_indices + gone.frame_indices, kind="stable")
            for name in ("observations", "scores", "frames", "frame_indices"):
                joined = getattr(keep, name) + getattr(gone, name)
                setattr(keep, name, [joined[k] for k in order])
            keep.misses += gone.misses
            keep.refit()
            self._objects.remove(gone)
            merged.append(gone.id)
            again = True
        return tuple(merged)

    def to_dict(self) -> dict:
        c = self.config
        return {
            "version": MAP_VERSION,
            "frame": "the poses' world turned so that y is gravity, down (docs/mapping.md)",
            "map_from_world": None if self.alignment is None else self.alignment.tolist(),
            "world_down": None if self.world_down is None else self.world_down.tolist(),
            "gravity_spread_deg": round(float(np.max(self._down_angles, initial=0.0)), 3),
            "frames_mapped": self.frames_mapped,
            "frames_skipped": dict(self.frames_skipped),
            "config": {
                "min_score": c.min_score,
                "max_centre_m": c.gates.max_centre_m,
                "min_iou": c.gates.min_iou,
                "min_support": c.min_support,
                "max_misses": c.max_misses,
                "max_range_m": c.max_range_m,
                "merge_iou": c.merge_iou,
            },
            "dropped": len(self.dropped),
            "objects": [o.to_dict(c.min_support) for o in self._objects],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    def write(self, path: str | os.PathLike) -> None:
        """Write ``to_json()`` atomically (a reader never sees half a map)."""
        atomic_write_bytes(path, (self.to_json() + "\n").encode("utf-8"))


def _turn_to_y(down: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the unit vector ``down`` to [0, 1, 0] (Rodrigues)."""
    down = np.asarray(down, np.float64) / np.linalg.norm(down)
    y = np.array([0.0, 1.0, 0.0])
    axis = np.cross(down, y)
    s, c = float(np.linalg.norm(axis)), float(down @ y)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def _rounded(values: np.ndarray) -> list[float]:
    return [round(float(v), 6) for v in values]


@dataclass(frozen=True)
class MappedObjects:
    """The confirmed objects of a map file: class names, boxes (N, 7) in the map's frame (a3d's
    7-vector: centre, l, w, h, yaw about y), scores (N,) and the frames that detected each (N,)."""

    classes: list[str]
    boxes: np.ndarray
    scores: np.ndarray
    support: np.ndarray


def read_confirmed(path: str | os.PathLike, within_deg: float = MAP_TURN_DEG) -> MappedObjects:
    """A map file's (``ObjectMap.write``) confirmed objects, where its frame is its recording's
    world turned by at most ``within_deg`` (a recording whose world has y down); every problem is
    one InputError naming the file."""
    doc = parse_json(read_bytes(path), str(path), "object map")
    objects = doc.get("objects") if isinstance(doc, dict) else None
    if not isinstance(objects, list):
        raise InputError(f"{path}: not an object map (a3d-run --map's map.json): no objects list")
    turn = doc.get("map_from_world")
    try:
        rotation = np.eye(3) if turn is None else np.asarray(turn, np.float64)[:3, :3]
        degrees = rotation_deg(rotation)
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{path}: map_from_world must be a 4 x 4 matrix") from None
    if degrees > within_deg:
        raise InputError(f"{path}: the map's frame is turned {degrees:.1f} degrees from its recording's "
                         "world, so that world's y is not down (a3d-world-boxes needs y down)")  # fmt: skip
    rows = []
    for k, item in enumerate(objects):
        if not isinstance(item, dict) or not item.get("confirmed"):
            continue
        try:
            box = [*map(float, item["centre"]), *map(float, item["size"]), float(item["yaw"])]
            rows.append((str(item["class"]), box, float(item["score"]), int(item["support"])))
        except (KeyError, TypeError, ValueError):
            needs = "a class, centre, size, yaw, score and support"
            raise InputError(f"{path}: objects[{k}] needs {needs}") from None
        if rows[-1][0] not in CLASSES or len(box) != 7 or not np.all(np.isfinite(box)) or min(box[3:6]) <= 0:
            raise InputError(f"{path}: objects[{k}] is no box of the 19 classes: {item['class']!r}, {box}")
    return MappedObjects(
        classes=[row[0] for row in rows],
        boxes=np.array([row[1] for row in rows], np.float64).reshape(-1, 7),
        scores=np.array([row[2] for row in rows], np.float64),
        support=np.array([row[3] for row in rows], np.int64),
    )
