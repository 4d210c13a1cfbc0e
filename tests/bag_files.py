"""Bags written with rosbags for the tests: a realsense-ros-like ROS 1 bag, the same as a ROS 2
bag, and a RealSense SDK recording (its ``/device_0/sensor_*`` layout, depth unregistered).

Frames are a3d-synth frames: colour uint8 BGR, depth uint16 millimetres (as the frame folder
stores it). Stamps start at ``T0`` and step by 1/30 s; depth stamps lag colour by ``lag`` s.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from a3d.runtime.frontend.registration import DepthToColor
from a3d.runtime.structures.geometry import Intrinsics

T0 = 1_700_000_000.0
PERIOD = 1 / 30
COLOR = "/camera/color/image_raw"
COLOR_INFO = "/camera/color/camera_info"
ALIGNED = "/camera/aligned_depth_to_color/image_raw"
ALIGNED_INFO = "/camera/aligned_depth_to_color/camera_info"
RAW_DEPTH = "/camera/depth/image_rect_raw"
RAW_DEPTH_INFO = "/camera/depth/camera_info"
POSE = "/camera/pose"
Frames = Sequence[tuple[np.ndarray, np.ndarray]]  # (colour BGR uint8, depth uint16 mm)
Poses = Sequence[tuple[float, np.ndarray, np.ndarray]]  # (stamp, position xyz, quaternion xyzw)


def stamp_as_read(stamp: float) -> float:
    """The seconds a reader gets back from the header stamp ``_Messages.header`` writes."""
    sec = int(stamp)
    return sec + round((stamp - sec) * 1e9) * 1e-9


class _Messages:
    """Builds sensor_msgs of one typestore (ROS 1 Noetic or ROS 2 Humble)."""

    def __init__(self, ros2: bool) -> None:
        self.ros2 = ros2
        self.store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
        self.t = self.store.types

    def header(self, stamp: float, frame_id: str) -> object:
        sec = int(stamp)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((stamp - sec) * 1e9))
        if self.ros2:
            return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)
        return self.t["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=frame_id)

    def image(self, stamp: float, frame_id: str, pixels: np.ndarray, encoding: str) -> object:
        h, w = pixels.shape[:2]
        data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
        return self.t["sensor_msgs/msg/Image"](
            header=self.header(stamp, frame_id),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=data.size // h,
            data=data,
        )

    def camera_info(self, stamp: float, frame_id: str, K: Intrinsics, size: tuple[int, int]) -> object:
        matrix = K.matrix().reshape(-1)
        P = np.zeros(12)
        P[[0, 2, 5, 6, 10]] = matrix[[0, 2, 4, 5, 8]]
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        fields = dict(
            header=self.header(stamp, frame_id),
            height=size[0],
            width=size[1],
            distortion_model="plumb_bob",
            binning_x=0,
            binning_y=0,
            roi=roi,
        )
        names = ("d", "k", "r", "p") if self.ros2 else ("D", "K", "R", "P")
        values = (np.zeros(5), matrix, np.eye(3).reshape(-1), P)
        return self.t["sensor_msgs/msg/CameraInfo"](**fields, **dict(zip(names, values, strict=True)))

    def pose(self, stamp: float, position: np.ndarray, quaternion: np.ndarray) -> object:
        """A geometry_msgs/PoseStamped in frame ``world``."""
        x, y, z, w = (float(v) for v in quaternion)
        pose = self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](
                x=float(position[0]), y=float(position[1]), z=float(position[2])
            ),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        )
        return self.t["geometry_msgs/msg/PoseStamped"](header=self.header(stamp, "world"), pose=pose)

    def tf(
        self, stamp: float, parent: str, child: str, position: np.ndarray, quaternion: np.ndarray
    ) -> object:
        """A tf2_msgs/TFMessage of one transform ``parent`` -> ``child`` (the child's pose in it)."""
        x, y, z, w = (float(v) for v in quaternion)
        transform = self.t["geometry_msgs/msg/Transform"](
            translation=self.t["geometry_msgs/msg/Vector3"](x=position[0], y=position[1], z=position[2]),
            rotation=self.t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        )
        stamped = self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp, parent), child_frame_id=child, transform=transform
        )
        return self.t["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def transform(self, R: np.ndarray, t: np.ndarray) -> object:
        w = np.sqrt(max(1e-12, 1 + np.trace(R))) / 2
        q = [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w]
        return self.t["geometry_msgs/msg/Transform"](
            translation=self.t["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
            rotation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )


class _Bag:
    """One bag being written: ``add(topic, msg, stamp)`` adds a connection on first use."""

    def __init__(self, path: Path, ros2: bool) -> None:
        self.m = _Messages(ros2)
        self.writer = Writer2(path, version=9) if ros2 else Writer1(path)
        self.connections: dict[str, object] = {}

    def __enter__(self) -> _Bag:
        self.writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def add(self, topic: str, msg: object, stamp: float) -> None:
        msgtype = msg.__msgtype__
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.m.store)
        store = self.m.store
        data = store.serialize_cdr(msg, msgtype) if self.m.ros2 else store.serialize_ros1(msg, msgtype)
        self.writer.write(self.connections[topic], round(stamp * 1e9), data)


def write_driver_bag(
    path: Path,
    frames: Frames,
    K: Intrinsics,
    ros2: bool = False,
    lag: float = 0.004,
    with_raw_depth: bool = True,
    with_aligned: bool = True,
    depth_32f: bool = False,
    poses: Poses = (),
    pose_topics: Sequence[str] = (POSE,),
    tf: Poses = (),
    tf_parent: str = "map",
) -> None:
    """A realsense-ros-like bag: colour, aligned depth (16UC1 mm, or 32FC1 m) with camera_info,
    an unregistered raw depth topic beside it (which the reader must not pick) and ``poses`` on
    each of ``pose_topics`` as PoseStamped, ``tf`` on ``/tf`` as ``tf_parent`` -> the colour
    camera's frame."""
    with _Bag(path, ros2) as bag:
        m = bag.m
        for stamp, position, quaternion in poses:
            for topic in pose_topics:
                bag.add(topic, m.pose(stamp, position, quaternion), stamp)
        for stamp, position, quaternion in tf:
            bag.add("/tf", m.tf(stamp, tf_parent, "camera_color_optical_frame", position, quaternion), stamp)
        for i, (color, depth) in enumerate(frames):
            stamp = T0 + i * PERIOD
            size = color.shape[:2]
            bag.add(COLOR, m.image(stamp, "camera_color_optical_frame", color[..., ::-1], "rgb8"), stamp)
            bag.add(COLOR_INFO, m.camera_info(stamp, "camera_color_optical_frame", K, size), stamp)
            depth_stamp = stamp + lag
            if with_aligned:
                pixels, encoding = (
                    (depth.astype(np.float32) / 1000, "32FC1") if depth_32f else (depth, "16UC1")
                )
                msg = m.image(depth_stamp, "camera_color_optical_frame", pixels, encoding)
                bag.add(ALIGNED, msg, depth_stamp)
                bag.add(
                    ALIGNED_INFO,
                    m.camera_info(depth_stamp, "camera_color_optical_frame", K, size),
                    depth_stamp,
                )
            if with_raw_depth:
                bag.add(
                    RAW_DEPTH,
                    m.image(depth_stamp, "camera_depth_optical_frame", depth // 2, "16UC1"),
                    depth_stamp,
                )


def write_sdk_bag(
    path: Path,
    frames: Frames,
    K: Intrinsics,
    calibration: DepthToColor,
    depth_units: float = 0.001,
    reference_to_color: tuple[np.ndarray, np.ndarray] | None = None,
    with_extrinsics: bool = True,
    with_color: bool = True,
) -> None:
    """A RealSense SDK recording (ROS 1, file version 3), complete enough for the SDK's own
    playback: ``frames`` hold colour and the depth camera's own depth (uint16 in ``depth_units``
    metres) of ``calibration``'s depth camera. Extrinsics are written as the SDK writes them,
    each stream's from a reference stream (``p_stream = R p_ref + t``): ``reference_to_color``
    for colour (default identity), the depth stream's following from ``calibration``."""
    with _Bag(path, ros2=False) as bag:
        m, t = bag.m, bag.m.t
        t0 = T0
        bag.add("/file_version", t["std_msgs/msg/UInt32"](data=3), t0)
        key_value = t["diagnostic_msgs/msg/KeyValue"]
        for key, value in (("Name", "Intel RealSense D435"), ("Serial Number", "000000000000")):
            bag.add("/device_0/info", key_value(key=key, value=value), t0)
        bag.add("/device_0/sensor_0/info", key_value(key="Name", value="Stereo Module"), t0)
        bag.add("/device_0/sensor_1/info", key_value(key="Name", value="RGB Camera"), t0)
        bag.add(
            "/device_0/sensor_0/option/Depth Units/value", t["std_msgs/msg/Float32"](data=depth_units), t0
        )
        depth_prefix, color_prefix = "/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"
        bag.m.store.register(get_types_from_msg(_STREAM_INFO, "realsense_msgs/msg/StreamInfo"))
        info = bag.m.store.types["realsense_msgs/msg/StreamInfo"]
        bag.add(f"{depth_prefix}/info", info(fps=30, encoding="mono16", is_recommended=True), t0)
        bag.add(f"{color_prefix}/info", info(fps=30, encoding="rgb8", is_recommended=True), t0)
        kd = calibration.depth_intrinsics
        bag.add(f"{depth_prefix}/info/camera_info", m.camera_info(t0, "0", kd, frames[0][1].shape), t0)
        bag.add(f"{color_prefix}/info/camera_info", m.camera_info(t0, "0", K, frames[0][0].shape[:2]), t0)
        if with_extrinsics:
            Rc, tc = reference_to_color or (np.eye(3), np.zeros(3))
            # p_color = Rc p_ref + tc = R p_depth + t  =>  p_depth = R^T (Rc p_ref + tc - t)
            Rd, td = calibration.R.T @ Rc, calibration.R.T @ (tc - calibration.t)
            bag.add(f"{depth_prefix}/tf/0", m.transform(Rd, td), t0)
            bag.add(f"{color_prefix}/tf/0", m.transform(Rc, tc), t0)
        for i, (color, depth) in enumerate(frames):
            stamp = t0 + 0.5 + i * PERIOD
            bag.add(f"{depth_prefix}/image/data", m.image(stamp + 0.003, "0", depth, "mono16"), stamp + 0.003)
            if with_color:
                bag.add(f"{color_prefix}/image/data", m.image(stamp, "0", color[..., ::-1], "rgb8"), stamp)


_STREAM_INFO = "uint32 fps\nstring encoding\nbool is_recommended\n"  # realsense_msgs/StreamInfo
