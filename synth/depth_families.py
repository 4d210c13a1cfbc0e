"""Depth errors of the common families of RGB-D camera, from the exact z-depth of a frame.

Each family fails in its own way, and a detector that has seen only one learns its habits:

* ``structured-light`` (Kinect v1): ``a3d.synth.sensor.sense_depth``, disparity quantisation,
  projector shadows left of near objects, holes on dark surfaces and at glancing angles;
* ``stereo`` (RealSense D4xx, active stereo): the same triangulation law (noise growing with z^2,
  quantised disparity, an occlusion band beside near objects), plus holes on texture-less
  surfaces (plain walls, doors, screens) once they are too far for the projected pattern;
* ``tof`` (Kinect v2, Azure Kinect): noise that grows slowly with depth and more on dark
  surfaces, *flying pixels* (depths between foreground and background along depth edges),
  *multipath* (concave corners read too far: light bounced off the neighbouring surface), and no
  depth outside the depth camera's narrower field registered into the wider colour image;
* ``lidar`` (iPhone / iPad LiDAR): a coarse native grid (192 x 256) upsampled to the image, which
  smears every edge, a short range (5 m) and smooth noise.

``sense`` picks the family of ``DepthSensor.family``; the structured-light branch is
``sense_depth`` itself, so sets rendered with it are unchanged.
"""

from __future__ import annotations

import cv2
import numpy as np

from a3d.synth.sensor import DepthSensor, blobs, clumpy_uniform, depth_sigma, gaussian, sense_depth
from a3d.synth.shading import ambient_occlusion

FAMILIES = ("structured-light", "stereo", "tof", "lidar")


def sense(
    rng: np.random.Generator,
    z: np.ndarray,
    fx: float,
    albedo_lum: np.ndarray,
    cos_inc: np.ndarray,
    s: DepthSensor,
) -> np.ndarray:
    """float32 depth (metres, 0 = missing) of family ``s.family`` from the exact depth z (H, W)."""
    if s.family == "structured-light":
        out = sense_depth(rng, z, fx, albedo_lum, cos_inc, s)
    elif s.family == "stereo":
        out = sense_depth(rng, z, fx, albedo_lum, cos_inc, s)
        out[textureless_holes(rng, z, albedo_lum, s.textureless_drop)] = 0.0
    elif s.family == "tof":
        out = tof_depth(rng, z, albedo_lum, cos_inc, s)
    elif s.family == "lidar":
        out = lidar_depth(rng, z, albedo_lum, s)
    else:
        raise ValueError(f"DepthSensor: family must be one of {FAMILIES}, not {s.family!r}")
    if s.coverage < 1.0:  # outside the depth camera's field of view
        W = z.shape[1]
        margin = round(W * (1 - s.coverage) / 2)
        out[:, :margin] = 0.0
        out[:, W - margin :] = 0.0
    return out


def depth_edges(z: np.ndarray, jump: float = 0.04) -> np.ndarray:
    """(H, W) bool: pixels next to a depth step of more than ``jump`` times their depth."""
    lo = cv2.erode(z, np.ones((3, 3), np.uint8))
    hi = cv2.dilate(z, np.ones((3, 3), np.uint8))
    return (hi - lo) > jump * z


def textureless_holes(
    rng: np.random.Generator, z: np.ndarray, albedo_lum: np.ndarray, p: float
) -> np.ndarray:
    """Stereo matching fails on plain surfaces: holes where the albedo's local contrast is low,
    more often the further the surface (the projected dot pattern fades), in clumps."""
    if p <= 0:
        return np.zeros(z.shape, bool)
    lum = albedo_lum.astype(np.float32)
    mean = cv2.blur(lum, (9, 9))
    contrast = np.sqrt(np.maximum(cv2.blur(lum * lum, (9, 9)) - mean * mean, 0)) / np.maximum(mean, 0.02)
    plain = np.clip((0.05 - contrast) / 0.05, 0, 1)
    far = np.clip((z - 1.2) / 2.0, 0, 1)
    return clumpy_uniform(rng, z.shape, 4.0) < p * plain * far


def tof_depth(
    rng: np.random.Generator, z: np.ndarray, albedo_lum: np.ndarray, cos_inc: np.ndarray, s: DepthSensor
) -> np.ndarray:
    """Time-of-flight depth: multipath bias, flying pixels, noise, low-return holes (see the module)."""
    H, W = z.shape
    zf = z.astype(np.float32)
    concave = (1 - ambient_occlusion(zf)) / 0.45  # 0 flat or convex, 1 a deep corner
    out = zf + np.float32(s.multipath) * concave.astype(np.float32)
    if s.flying > 0:
        lo = cv2.erode(zf, np.ones((3, 3), np.uint8))
        hi = cv2.dilate(zf, np.ones((3, 3), np.uint8))
        fly = depth_edges(zf) & (rng.random((H, W), dtype=np.float32) < s.flying)
        mix = rng.random((H, W), dtype=np.float32)
        out = np.where(fly, lo + mix * (hi - lo), out)
    dark = np.clip((s.dark_albedo * 3 - albedo_lum) / (s.dark_albedo * 3), 0, 1)
    sigma = depth_sigma(zf, s) * (1 + 3 * dark)
    out = out + sigma.astype(np.float32) * gaussian(rng, (H, W))
    drop = (z < s.min_depth) | (z > s.max_depth)
    glancing = np.clip((s.glancing_cos - np.abs(cos_inc)) / s.glancing_cos, 0, 1) * 0.6
    p = 1 - (1 - 0.8 * dark * np.clip(z / s.max_depth * 2, 0, 1)) * (1 - glancing)
    drop |= clumpy_uniform(rng, (H, W), 1.5) < p
    drop |= blobs(rng, H, W)
    return np.where(drop, 0.0, out).astype(np.float32)


def lidar_depth(
    rng: np.random.Generator, z: np.ndarray, albedo_lum: np.ndarray, s: DepthSensor
) -> np.ndarray:
    """LiDAR depth: sampled on the coarse native grid, noisy there, upsampled bilinearly."""
    H, W = z.shape
    h, w = s.native_size if s.native_size != (0, 0) else (H, W)
    coarse = cv2.resize(z.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    coarse = coarse + depth_sigma(coarse, s).astype(np.float32) * gaussian(rng, (h, w))
    dark = cv2.resize(albedo_lum.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) < s.dark_albedo
    coarse[(coarse < s.min_depth) | (coarse > s.max_depth) | (dark & (rng.random((h, w)) < 0.5))] = 0.0
    valid = cv2.resize((coarse > 0).astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
    up = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_LINEAR)
    return np.where(valid > 0.99, up, 0.0).astype(np.float32)  # no depth where a hole blends in
