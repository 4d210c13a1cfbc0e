"""Presets of common RGB-D cameras: the registered frame's size, field of view and depth errors.

A frame of a device is its colour image with the depth registered into it, at a working size
of 640 pixels across (times ``scale``): the colour camera's horizontal field of view sets the
focal length, and the depth family and parameters (``a3d.synth.depth_families``) its errors.
The values approximate the makers' published figures; they aim at each family's look, not at
one calibrated unit:

=================  ==========  =====  ================  =============================================
device             frame       HFOV   depth family      what goes wrong
=================  ==========  =====  ================  =============================================
kinect-v1          480 x 640   62     structured light  Nguyen et al.'s error law, 1/8-px disparity
kinect-v2          360 x 640   84     time of flight    flying pixels, multipath, depth FOV 70 deg
azure-kinect       360 x 640   90     time of flight    less noise, depth (NFOV) 75 deg across
realsense-d435     360 x 640   69     active stereo     5 cm baseline, texture-less holes far away
realsense-d455     360 x 640   90     active stereo     9.5 cm baseline
iphone-lidar       480 x 640   63     LiDAR             192 x 256 native depth, 5 m range
=================  ==========  =====  ================  =============================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from a3d.runtime.structures.geometry import Intrinsics
from a3d.synth.sensor import SENSORS, DepthSensor


@dataclass(frozen=True)
class Device:
    """One camera: name, registered frame size (H, W) at scale 1, colour HFOV (degrees), depth model."""

    name: str
    size: tuple[int, int]
    hfov_deg: float
    depth: DepthSensor

    def frame(self, scale: float = 1.0) -> tuple[tuple[int, int], Intrinsics]:
        """Image size (H, W) and pinhole intrinsics (square pixels, centred) at ``scale``."""
        H, W = round(self.size[0] * scale), round(self.size[1] * scale)
        f = (W / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        return (H, W), Intrinsics(f, f, (W - 1) / 2, (H - 1) / 2)


_TOF = DepthSensor(
    family="tof", min_depth=0.5, max_depth=4.5, sigma0=0.003, sigma2=0.0008, flying=0.7, multipath=0.04
)
_STEREO = DepthSensor(
    family="stereo",
    baseline=0.05,
    subpixel=10.0,
    min_depth=0.3,
    max_depth=8.0,
    sigma0=0.001,
    sigma2=0.004,
    edge_drop=0.6,
    textureless_drop=0.7,
)

DEVICES: dict[str, Device] = {
    d.name: d
    for d in (
        Device("kinect-v1", (480, 640), 62.0, SENSORS["kinect-v1"]),
        Device("kinect-v2", (360, 640), 84.1, replace(_TOF, coverage=0.785)),
        Device(
            "azure-kinect",
            (360, 640),
            90.0,
            replace(_TOF, max_depth=5.5, sigma0=0.002, flying=0.5, coverage=0.77),
        ),
        Device("realsense-d435", (360, 640), 69.0, _STEREO),
        Device("realsense-d455", (360, 640), 90.0, replace(_STEREO, baseline=0.095)),
        Device(
            "iphone-lidar",
            (480, 640),
            63.0,
            DepthSensor(
                family="lidar",
                min_depth=0.2,
                max_depth=5.0,
                sigma0=0.004,
                sigma2=0.002,
                native_size=(192, 256),
            ),
        ),
    )
}
