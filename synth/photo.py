"""Real light and a real camera's colour pipeline (``SceneConfig.real_light``).

The default renderer lights rooms with ceiling lights and takes pictures with a well-behaved
camera (``a3d.synth.sensor.sense_colour``). Real frames are harsher:

* daylight: often a strong directional light through the windows (with the sky's blue tint),
  and window panes that glow, so that the auto exposure meters against a blown-out window;
* metering errors of up to a stop either way, and white balance left partly uncorrected (warm
  under tungsten, blue in shade) with a green-magenta tint;
* optical defocus and hand-shake streaks (sized for frames 640 pixels across), then shot and
  read noise at a random gain (ISO), with colour (demosaicing) noise, a contrast and saturation
  curve, sometimes over-sharpening;
* JPEG compression at quality 55-95.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from a3d.synth.sensor import gaussian, motion_kernel, vignette
from a3d.synth.shading import Lights

DAYLIGHT = np.array([0.88, 0.95, 1.05])  # linear RGB of the sky's light
DAYLIGHT_SHARE = 0.7  # frames with daylight through the windows


def add_daylight(rng: np.random.Generator, lights: Lights, window_yaw: float | None = None) -> Lights:
    """``lights`` with (probability DAYLIGHT_SHARE) a strong directional daylight in place of the
    renderer's weak sun, and the sky's light added to the ambient term. The light comes in
    through a window facing tilt-frame yaw ``window_yaw`` (its inward direction), within 0.6 rad
    of it; from anywhere without one."""
    if rng.random() >= DAYLIGHT_SHARE:
        return lights
    elevation = float(rng.uniform(0.2, 0.9))
    if window_yaw is None:
        azimuth = float(rng.uniform(0, 2 * math.pi))
    else:
        azimuth = window_yaw + float(rng.uniform(-0.6, 0.6))
    c, s = math.cos(elevation), math.sin(elevation)
    direction = np.array([c * math.sin(azimuth), s, c * math.cos(azimuth)])  # tilt frame: +y is down
    power = DAYLIGHT * float(rng.uniform(0.6, 2.5))
    ambient = lights.ambient + DAYLIGHT * float(rng.uniform(0.05, 0.25))
    return Lights(ambient, lights.positions, lights.powers, direction, power)


def glow(rng: np.random.Generator, radiance: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``radiance`` with the pixels of ``mask`` (window panes) set to bright sky, 1.5-5 times the
    scene's 95th-percentile radiance: a window blows out as in real photographs."""
    if not mask.any():
        return radiance
    level = float(np.percentile(radiance[::4, ::4], 95)) * float(rng.uniform(1.5, 5.0))
    out = radiance.copy()
    out[mask] = (DAYLIGHT * level).astype(np.float32)
    return out


def sense_colour_real(rng: np.random.Generator, radiance: np.ndarray) -> np.ndarray:
    """uint8 BGR image of linear RGB radiance (H, W, 3) through a consumer camera (module docstring)."""
    H, W, _ = radiance.shape
    f32 = np.float32
    lum = radiance[::4, ::4] @ np.array([0.2126, 0.7152, 0.0722], f32)
    ev = float(np.clip(rng.normal(0.0, 0.45), -1.2, 1.0))  # metering error, stops
    exposure = 0.2 * 2.0**ev / max(float(lum.mean()), 1e-4)
    warm, tint = float(rng.normal(0.0, 0.12)), float(rng.normal(0.0, 0.04))
    wb = np.exp(np.array([warm, tint, -warm]))
    img = radiance * (exposure * wb / wb.mean()).astype(f32)
    img *= (1 - float(rng.uniform(0.15, 0.45)) * vignette(H, W))[..., None]
    px = W / 640  # blur sizes are given for frames 640 pixels across
    img = cv2.GaussianBlur(img, (0, 0), px * float(rng.uniform(0.3, 1.0)))  # defocus and optics
    if rng.random() < 0.3:
        img = cv2.filter2D(img, -1, motion_kernel(rng, max(2, round(3 * px)), max(3, round(10 * px))))
    iso = f32(math.exp(rng.uniform(0.0, math.log(8.0))))
    shot, read = f32(0.0015) * iso, f32(0.0015) * iso
    img = np.maximum(img, 0) + gaussian(rng, img.shape) * np.sqrt(np.maximum(img, 0) * shot + read * read)
    img = cv2.GaussianBlur(img, (0, 0), 0.6)  # demosaicing spreads the noise over neighbours
    img = np.clip(img, 0, 1) ** f32(1 / 2.2)
    grey = img @ np.array([0.299, 0.587, 0.114], f32)
    img = grey[..., None] + (img - grey[..., None]) * f32(rng.uniform(0.8, 1.3))  # saturation
    img = f32(0.5) + (img - f32(0.5)) * f32(rng.uniform(0.9, 1.3))  # contrast
    if rng.random() < 0.5:  # over-sharpening
        img = img + f32(rng.uniform(0.3, 1.0)) * (img - cv2.GaussianBlur(img, (0, 0), 1.5))
    bgr = np.ascontiguousarray(np.clip(img[..., ::-1] * 255 + 0.5, 0, 255).astype(np.uint8))
    ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(55, 96))])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(data, cv2.IMREAD_COLOR)
