"""Frames from ROS bags: ROS 1 ``.bag`` files, ROS 2 bag folders, RealSense SDK recordings.

Read through ``rosbags`` (pure Python; the ``bag`` extra), imported only when a bag is opened.

Two layouts are recognised from the topics:

* **Driver bags** (realsense-ros, Azure Kinect / Orbbec / ZED drivers, anything publishing
  ``sensor_msgs``): colour is the one Image topic in rgb8 / bgr8 / rgba8 / bgra8 or
  CompressedImage; depth the one Image in 16UC1 (millimetres) / 32FC1 (metres) or a
  16UC1 ``compressedDepth`` topic, topics whose names say registered (``aligned_depth_to_color``,
  ``depth_registered``) preferred, a raw topic preferred over its ``/compressed`` twin. When more
  than one fits, ``--color-topic`` / ``--depth-topic`` choose. Intrinsics come from the colour
  topic's ``camera_info``. Depth is registered to colour when its topic says so or its
  ``camera_info`` has the colour camera's ``frame_id``; otherwise it is in the depth camera's
  frame and is registered here (``a3d.runtime.frontend.registration``) with the depth camera's
  ``camera_info`` and the transform between the two frames in ``/tf_static``.
* **RealSense SDK recordings** (``rs.recorder`` / the RealSense Viewer, ROS 1 format):
  ``/device_0/sensor_S/{Depth_0,Color_0}/image/data``, their ``info/camera_info``, the depth
  units in ``/device_0/sensor_S/option/Depth Units/value`` (``property`` in file version 2) and
  each stream's extrinsics from the device's reference stream in ``.../tf/0`` (what the SDK's
  own playback reads: ``p_stream = R p_reference + t``). The SDK records
  depth unregistered, so it always goes through registration.

Poses: a ``geometry_msgs/PoseStamped`` or ``nav_msgs/Odometry`` topic (``--pose-topic``, or the
bag's only topic of those types) is read as the colour camera's camera-to-world pose over time;
each frame gets the pose at its colour stamp (a3d.runtime.sources.trajectory: interpolated, none
outside the topic's span or across a gap of more than ``max_pose_gap`` seconds, a note saying why).
Without a pose topic, ``/tf`` transforms from ``world``, ``map`` or ``odom`` straight to the colour
``camera_info``'s frame are that trajectory; longer chains (map -> base_link -> camera) are not
composed.

Colour and depth are paired by header stamp: each colour image takes the depth image nearest in
time, if within ``PAIR_TOLERANCE``; colour images without one are skipped and counted in one
line. Anything that makes the bag unusable as a whole (no depth topic, an ambiguous topic, no
intrinsics, depth that cannot be registered or whose registration cannot be told) is one
``InputError`` when the bag is opened, before any frame is read.
"""

from __future__ import annotations

import re
import threading
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.registration import DepthToColor, register_depth
from a3d.runtime.sources.arrays import depth_units_to_metres, frame_from_arrays
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.registry import SourceOptions
from a3d.runtime.sources.ros_messages import (
    COLOR_ENCODINGS,
    DEPTH_ENCODINGS,
    POSE_TYPES,
    color_of,
    depth_of,
    header_seconds,
    image_encoding,
    intrinsics_of,
    is_compressed,
    pose_row_of,
    transform_of,
    transform_row_of,
)
from a3d.runtime.sources.trajectory import DEFAULT_MAX_GAP, Trajectory, frame_pose, trajectory_of
from a3d.runtime.sources.wording import keyword, option
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics
from a3d.runtime.structures.pose import quaternion_to_rotation

EXTRA = "pip install 'a3d[bag]'"
PAIR_TOLERANCE = 0.02  # seconds between a colour image's stamp and its depth image's
MILLIMETRE = 0.001
_IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_REGISTERED_NAMES = ("aligned_depth_to_color", "depth_registered", "registered")
WORLD_FRAMES = ("world", "map", "odom")  # /tf parents whose transform to the camera is its pose
_SDK_STREAM = re.compile(r"^/device_0/sensor_(\d+)/(Depth|Color)_0/image/data$")


def claims(spec: str) -> bool:
    """A ``.bag`` file or a ROS 2 bag folder (``metadata.yaml`` inside)."""
    path = Path(spec)
    return (path.is_file() and path.suffix.lower() == ".bag") or (path / "metadata.yaml").is_file()


def open_source(spec: str, options: SourceOptions) -> BagSource:
    return BagSource(Path(spec), options)


@dataclass(frozen=True)
class _Message:
    """Where one message is: its connection, bag time (ns) and rank among that connection's
    messages at the same bag time; ``stamp`` its header stamp (s)."""

    connection: Any
    bag_time: int
    rank: int
    stamp: float


@dataclass(frozen=True)
class _Plan:
    """What the bag's frames are made of (see the module docstring)."""

    color_topic: str
    depth_topic: str
    intrinsics: Intrinsics
    depth_scale: float  # metres per unit of integer depth
    calibration: DepthToColor | None  # None: depth already registered to colour


class BagSource:
    """The paired colour/depth frames of one bag (a ``FrameSource``)."""

    def __init__(self, path: Path, options: SourceOptions) -> None:
        self.path = path
        self.options = options
        self.incomplete: list[str] = []
        self._lock = threading.Lock()  # one reader, shared by loaders that may run on another thread
        self._reader = _open_reader(path)
        self._topics: dict[str, list[Any]] = defaultdict(list)
        for connection in self._reader.connections:
            self._topics[connection.topic].append(connection)
        sdk = any(_SDK_STREAM.match(topic) for topic in self._topics)
        self.plan = self._sdk_plan() if sdk else self._driver_plan()
        self._pairs = self._pair()
        self.max_gap = float(options.extra.get("max_pose_gap", DEFAULT_MAX_GAP))  # type: ignore[arg-type]
        self.trajectory = self._trajectory()

    @property
    def has_poses(self) -> bool:
        """Whether the bag has poses, a topic or /tf (frames outside their span still go without)."""
        return self.trajectory is not None

    # ------------------------------------------------------------------------- frames

    def __len__(self) -> int:
        return len(self._pairs)

    def __iter__(self) -> Iterator[FrameLoader]:
        start = self._pairs[0][0].stamp if self._pairs else 0.0
        for index, (color, depth) in enumerate(self._pairs):
            name = f"{self.path.stem}_{index:06d}"
            origin = f"{self.path}@{color.stamp - start:.3f}s"
            yield FrameLoader(name, origin, lambda c=color, d=depth, n=name, o=origin: self._load(c, d, n, o))

    def _load(self, color: _Message, depth: _Message, name: str, origin: str) -> Frame:
        try:
            with self._lock:
                color_msg, depth_msg = self._read(color), self._read(depth)
            rgb = color_of(color_msg)
            units = depth_of(depth_msg)
            scale = self.options.depth_scale or self.plan.depth_scale
            metres = depth_units_to_metres(units, scale) if units.dtype == np.uint16 else units
            if self.plan.calibration is not None:
                metres = register_depth(metres, self.plan.calibration, self.plan.intrinsics, rgb.shape[:2])
            elif metres.shape != rgb.shape[:2] and self.options.resize_depth:
                metres = cv2.resize(metres, rgb.shape[1::-1], interpolation=cv2.INTER_NEAREST)
            intrinsics = self.options.intrinsics or self.plan.intrinsics
            pose, note = frame_pose(self.trajectory, color.stamp, self.max_gap, origin)
            frame = frame_from_arrays(
                rgb, metres, intrinsics, name=name, origin=origin, timestamp=color.stamp, pose=pose
            )
            return replace(frame, pose_note=note)
        except InputError as e:
            raise InputError(f"{origin}: {e}") from None

    def _read(self, where: _Message) -> Any:
        generator = self._reader.messages([where.connection], start=where.bag_time, stop=where.bag_time + 1)
        for rank, (connection, _, raw) in enumerate(generator):
            if rank == where.rank:
                return self._reader.deserialize(raw, connection.msgtype)
        raise InputError(f"{where.connection.topic}: message at {where.bag_time} ns is gone")

    def _pair(self) -> list[tuple[_Message, _Message]]:
        """Each colour message with the depth message nearest in header stamp, within tolerance."""
        colors = self._index(self.plan.color_topic)
        depths = sorted(self._index(self.plan.depth_topic), key=lambda m: m.stamp)
        if not depths:
            raise InputError(f"{self.path}: depth topic {self.plan.depth_topic} has no messages")
        stamps = np.array([m.stamp for m in depths])
        pairs = []
        for color in sorted(colors, key=lambda m: m.stamp):
            i = int(np.searchsorted(stamps, color.stamp))
            near = min(
                (j for j in (i - 1, i) if 0 <= j < len(depths)), key=lambda j: abs(stamps[j] - color.stamp)
            )
            if abs(stamps[near] - color.stamp) <= PAIR_TOLERANCE:
                pairs.append((color, depths[near]))
        if len(pairs) < len(colors):
            self.incomplete.append(
                f"{self.path}: {len(colors) - len(pairs)} of {len(colors)} colour images have no depth image "
                f"within {PAIR_TOLERANCE} s (skipped)"
            )
        return pairs

    def _index(self, topic: str) -> list[_Message]:
        """Every message of ``topic`` with its header stamp (one pass over the topic)."""
        out, seen = [], defaultdict(int)
        for connection, bag_time, raw in self._reader.messages(self._topics[topic]):
            key = (id(connection), bag_time)
            msg = self._reader.deserialize(raw, connection.msgtype)
            out.append(_Message(connection, bag_time, seen[key], header_seconds(msg)))
            seen[key] += 1
        return out

    # ------------------------------------------------------------------------- poses

    def _pose_topic(self) -> str | None:
        """``--pose-topic``, else the bag's only pose topic (None: none, or several: a note)."""
        wanted = self.options.extra.get("pose_topic")
        if wanted is not None:
            types = self._topics.get(str(wanted))
            if not types or types[0].msgtype not in POSE_TYPES:
                raise InputError(
                    f"{keyword('pose_topic')}: {wanted} is not a PoseStamped or Odometry topic of {self.path}"
                )
            return str(wanted)
        found = sorted(t for t, c in self._topics.items() if c[0].msgtype in POSE_TYPES)
        if len(found) > 1:
            self.incomplete.append(
                f"{self.path}: several pose topics ({', '.join(found)}), none used; "
                f"choose one with {option('pose_topic')}"
            )
        return found[0] if len(found) == 1 else None

    def _trajectory(self) -> Trajectory | None:
        """The pose topic's poses as a trajectory, else the colour camera's in ``/tf``."""
        topic = self._pose_topic()
        if topic is None:
            return self._tf_trajectory()
        return self._checked(topic, [pose_row_of(message) for message in self._all(topic)])

    def _tf_trajectory(self) -> Trajectory | None:
        """The colour camera frame's transforms in ``/tf`` from one of ``WORLD_FRAMES`` (a parent
        such as ``camera_link`` would pose the camera on its own mount); None when there are none
        (or from several world frames: a note), or its ``camera_info`` names no frame."""
        info = self._camera_info(self.plan.color_topic) if "/tf" in self._topics else None
        camera = info.header.frame_id.lstrip("/") if info is not None else ""
        if not camera:
            return None
        stamped = [
            s
            for m in self._all("/tf")
            for s in m.transforms
            if s.child_frame_id.lstrip("/") == camera and s.header.frame_id.lstrip("/") in WORLD_FRAMES
        ]
        parents = sorted({s.header.frame_id.lstrip("/") for s in stamped})
        if len(parents) != 1:
            if parents:
                self.incomplete.append(
                    f"{self.path}: /tf gives {camera} several parents ({', '.join(parents)}), so no poses"
                )
            return None
        return self._checked(f"/tf {parents[0]}->{camera}", [transform_row_of(s) for s in stamped])

    def _checked(self, what: str, rows: list[np.ndarray]) -> Trajectory:
        """A trajectory of ``rows``; a row with a bad quaternion is left out and noted (the
        frames near it then fall in a gap)."""
        good = []
        for row in rows:
            try:
                quaternion_to_rotation(row[4:], f"{self.path}: {what} at {row[0]:.6f}")
            except InputError as e:
                self.incomplete.append(str(e))
                continue
            good.append(row)
        return trajectory_of(np.array(good), self.path, f"{self.path.name} {what}")

    # ------------------------------------------------------------------------- layouts

    def _first(self, topic: str) -> Any | None:
        """The first message of ``topic`` (None if the topic is absent or empty)."""
        if topic not in self._topics:
            return None
        for connection, _, raw in self._reader.messages(self._topics[topic]):
            return self._reader.deserialize(raw, connection.msgtype)
        return None

    def _all(self, topic: str) -> list[Any]:
        return [
            self._reader.deserialize(raw, c.msgtype)
            for c, _, raw in self._reader.messages(self._topics[topic])
        ]

    def _driver_plan(self) -> _Plan:
        colors, depths = [], []
        for topic, connections in self._topics.items():
            if connections[0].msgtype not in _IMAGE_TYPES:
                continue
            first = self._first(topic)
            if first is None:
                continue
            encoding = image_encoding(first)
            if is_compressed(first):
                (depths if "compressedDepth" in encoding else colors).append(topic)
            elif encoding in COLOR_ENCODINGS:
                colors.append(topic)
            elif encoding in DEPTH_ENCODINGS:
                depths.append(topic)
        color = self._choose("color", colors, self.options.extra.get("color_topic"))
        depth = self._choose("depth", depths, self.options.extra.get("depth_topic"))
        color_info, depth_info = self._camera_info(color), self._camera_info(depth)
        intrinsics = self._intrinsics(color, color_info)
        return _Plan(
            color, depth, intrinsics, MILLIMETRE, self._driver_calibration(depth, color_info, depth_info)
        )

    def _choose(self, role: str, candidates: list[str], wanted: object) -> str:
        flag = f"--{role}-topic"
        if wanted is not None:
            if wanted not in self._topics:
                raise InputError(f"{flag}: {wanted} is not a topic of {self.path}")
            return str(wanted)
        # A raw topic is preferred over its image_transport twins (TOPIC/compressed, ...).
        candidates = [t for t in candidates if t.rsplit("/", 1)[0] not in candidates]
        if role == "depth":
            registered = [t for t in candidates if any(n in t for n in _REGISTERED_NAMES)]
            candidates = registered or candidates
        what = "colour (rgb8/bgr8/rgba8/bgra8 or compressed)" if role == "color" else "depth (16UC1/32FC1)"
        if not candidates:
            raise InputError(
                f"{self.path}: no {what} image topic (topics: {', '.join(sorted(self._topics))})"
            )
        if len(candidates) > 1:
            raise InputError(
                f"{self.path}: several {what} image topics ({', '.join(sorted(candidates))}); "
                f"choose one with {flag}"
            )
        return candidates[0]

    def _camera_info(self, image_topic: str) -> Any | None:
        """The ``camera_info`` beside an image topic (``.../image_raw`` -> ``.../camera_info``)."""
        parts = image_topic.split("/")
        for end in range(len(parts) - 1, 0, -1):
            info = self._first("/".join(parts[:end]) + "/camera_info")
            if info is not None:
                return info
        return None

    def _intrinsics(self, topic: str, info: Any | None) -> Intrinsics:
        if self.options.intrinsics is not None:
            return self.options.intrinsics
        if info is None:
            raise InputError(
                f"{self.path}: no camera_info for {topic}; give the intrinsics with {option('intrinsics')}"
            )
        try:
            return intrinsics_of(info)
        except InputError as e:
            given = option("intrinsics")
            raise InputError(f"{self.path}: {topic}: {e}; give the intrinsics with {given}") from None

    def _driver_calibration(
        self, depth: str, color_info: Any | None, depth_info: Any | None
    ) -> DepthToColor | None:
        """None when the depth is registered to colour, else what registering it takes."""
        if any(n in depth for n in _REGISTERED_NAMES):
            return None
        if depth_info is None or color_info is None:
            raise InputError(
                f"{self.path}: cannot tell whether {depth} is registered to colour (no camera_info for "
                f"{'it' if depth_info is None else 'the colour topic'}); record aligned_depth_to_color "
                f"or pick a registered depth topic with {option('depth_topic')}"
            )
        depth_frame, color_frame = depth_info.header.frame_id, color_info.header.frame_id
        if depth_frame == color_frame:
            return None
        R, t = self._static_transform(color_frame, depth_frame, depth)
        return DepthToColor(intrinsics_of(depth_info), R, t)

    def _static_transform(self, target: str, source: str, depth: str) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with ``p_target = R p_source + t`` from the ``/tf_static`` tree."""
        edges: dict[str, list[tuple[str, np.ndarray]]] = defaultdict(list)
        for message in self._all("/tf_static") if "/tf_static" in self._topics else []:
            for stamped in message.transforms:
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = transform_of(stamped.transform)
                parent, child = stamped.header.frame_id.lstrip("/"), stamped.child_frame_id.lstrip("/")
                edges[parent].append((child, T))  # p_parent = T p_child
                edges[child].append((parent, np.linalg.inv(T)))
        pose = {source.lstrip("/"): np.eye(4)}  # p_source = pose[f] p_f
        todo = [source.lstrip("/")]
        while todo:
            frame = todo.pop()
            for other, T in edges[frame]:
                if other not in pose:
                    pose[other] = pose[frame] @ T
                    todo.append(other)
        if target.lstrip("/") not in pose:
            raise InputError(
                f"{self.path}: registration not possible: {depth} is in frame {source!r}, colour in "
                f"{target!r}, and /tf_static does not connect them; record aligned_depth_to_color"
            )
        T = np.linalg.inv(pose[target.lstrip("/")])  # p_target = T p_source
        return T[:3, :3], T[:3, 3]

    def _sdk_plan(self) -> _Plan:
        streams = {
            m.group(2): (topic, m.group(1)) for topic in self._topics if (m := _SDK_STREAM.match(topic))
        }
        if "Depth" not in streams:
            raise InputError(
                f"{self.path}: RealSense recording without a depth stream (no .../Depth_0/image/data)"
            )
        if "Color" not in streams:
            raise InputError(
                f"{self.path}: RealSense recording without a colour stream (no .../Color_0/image/data)"
            )
        (depth, depth_sensor), (color, _) = streams["Depth"], streams["Color"]
        intrinsics = self._intrinsics(color, self._first(color.replace("/image/data", "/info/camera_info")))
        depth_info = self._first(depth.replace("/image/data", "/info/camera_info"))
        from_reference = {}  # the SDK's tf/0: extrinsics from the reference stream, p_S = R p_ref + t
        for role, topic in (("Depth", depth), ("Color", color)):
            message = self._first(topic.replace("/image/data", "/tf/0"))
            if message is None or depth_info is None:
                missing = "depth camera_info" if depth_info is None else f"{role}_0 extrinsics (tf/0)"
                raise InputError(f"{self.path}: registration not possible: the recording has no {missing}")
            from_reference[role] = np.eye(4)
            from_reference[role][:3, :3], from_reference[role][:3, 3] = transform_of(message)
        T = from_reference["Color"] @ np.linalg.inv(from_reference["Depth"])  # p_color = T p_depth
        calibration = DepthToColor(intrinsics_of(depth_info), T[:3, :3], T[:3, 3])
        return _Plan(color, depth, intrinsics, self._sdk_depth_units(depth_sensor), calibration)

    def _sdk_depth_units(self, sensor: str) -> float:
        value = self._first(f"/device_0/sensor_{sensor}/option/Depth Units/value")
        if value is not None:
            return float(value.data)
        for item in (
            self._all(f"/device_0/sensor_{sensor}/property")
            if f"/device_0/sensor_{sensor}/property" in self._topics
            else []
        ):
            if item.key == "Depth Units":
                return float(item.value)
        if self.options.depth_scale is not None:
            return self.options.depth_scale
        given = option("depth_scale")
        raise InputError(f"{self.path}: the recording has no Depth Units; give them with {given}")


def _open_reader(path: Path) -> Any:
    """An open ``rosbags`` AnyReader (InputError naming the extra when rosbags is missing)."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise InputError(f"{path}: reading bags needs rosbags: {EXTRA}") from None
    reader = AnyReader([path])
    try:
        reader.open()
    except Exception as e:  # rosbags raises its own error types per format
        raise InputError(f"{path}: not a readable bag ({type(e).__name__}: {e})") from None
    return reader
