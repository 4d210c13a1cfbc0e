"""Structured-light depth sensors (Kinect v1's error law) and a consumer colour camera.

Depth (metres, 0 = missing), from the exact z-depth of the rendered scene:

* axial error with standard deviation sigma(z) = sigma0 + sigma2 (z - 0.4)^2, the form Nguyen et
  al. 2012 measured for Kinect v1: Gaussian noise, partly correlated over a few pixels (the sensor
  matches 9x9 speckle windows), followed by disparity quantisation: the depth is snapped to the
  1/``subpixel``-pixel disparity steps of a 7.5 cm-baseline stereo pair at the colour camera's
  focal length, d = f b / z; the Gaussian part is reduced by the rounding's variance (step^2 / 12)
  so that the total matches sigma(z);
* missing depth: outside the 0.45-8 m range; in the projector's shadow beside occluding edges
  (the band of background pixels a nearer surface hides from a projector 7.5 cm to the right);
  randomly at depth discontinuities (a 1-2 pixel band); on dark surfaces (low IR return) and at
  glancing incidence; and in a few small random blobs (specular spots).

Two parameter sets (``SENSORS``): ``kinect-v1`` is Nguyen et al.'s Kinect v1 (sigma2 0.0019, 1/8-px
disparity): its error passes 5 cm beyond about 4.5 m (4.1 cm sigma and 8 cm steps at 5 m), so far
objects' depth no longer lies within 5 cm of their boxes. The default, ``a3d``, keeps the law at
under a third of that error (sigma2 0.0006, 1/12-px disparity: 1.4 cm sigma and 5.3 cm steps at
5 m), so that every annotated object's sensed surface stays within 5 cm of its box out to 8 m.

Colour: auto exposure, camera gamma, per-channel gain (white balance), vignetting, occasional
hand-shake motion blur, optics blur, signal-dependent noise, 8-bit quantisation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class DepthSensor:
    """Depth-sensor parameters (metres, pixels); the defaults are the ``a3d`` sensor."""

    baseline: float = 0.075
    subpixel: float = 12.0
    min_depth: float = 0.45
    max_depth: float = 8.0
    sigma0: float = 0.0012
    sigma2: float = 0.0006
    edge_drop: float = 0.5  # dropout probability in the band along depth discontinuities
    dark_albedo: float = 0.02  # albedo luminance below which IR return is unreliable
    glancing_cos: float = 0.12  # |cos incidence| below which depth is often lost
    # Other families of depth camera (a3d.synth.depth_families); the defaults are structured light.
    family: str = "structured-light"  # or "tof", "stereo", "lidar"
    flying: float = 0.0  # tof: share of the depth-edge band given flying pixels (mixed depths)
    multipath: float = 0.0  # tof: depth added (metres) in fully concave corners
    textureless_drop: float = 0.0  # stereo: hole probability on far texture-less surfaces
    native_size: tuple[int, int] = (0, 0)  # lidar: (H, W) of the native depth grid, upsampled
    coverage: float = 1.0  # share of the image width the depth camera's narrower field covers


SENSORS = {"a3d": DepthSensor(), "kinect-v1": DepthSensor(subpixel=8.0, sigma2=0.0019)}


def depth_sigma(z: np.ndarray, s: DepthSensor = DepthSensor()) -> np.ndarray:
    """Axial noise standard deviation (metres) at depth z (metres)."""
    return s.sigma0 + s.sigma2 * (z - 0.4) ** 2


def gaussian(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """float32 standard normal noise of ``shape`` from OpenCV's generator seeded by ``rng``
    (deterministic, and several times faster than numpy's for image-sized draws)."""
    out = np.empty(int(np.prod(shape)), np.float32)
    cv2.setRNGSeed(int(rng.integers(1 << 31)))
    cv2.randn(out, 0.0, 1.0)
    return out.reshape(shape)


def clumpy_uniform(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Spatially correlated noise with a roughly uniform [0, 1] marginal (logistic of a smooth field)."""
    g = cv2.GaussianBlur(gaussian(rng, shape), (0, 0), sigma)
    g *= 2.0 * sigma * np.sqrt(np.pi)  # unit variance again after the blur
    return 1.0 / (1.0 + np.exp(-1.702 * g))


def axial_noise(
    rng: np.random.Generator, z: np.ndarray, fx: float, s: DepthSensor = DepthSensor()
) -> np.ndarray:
    """float32 depth with the sensor's axial error only (Gaussian, partly correlated, then snapped
    to the disparity steps of a camera of focal length ``fx``): no holes (0 in z stays 0)."""
    H, W = z.shape
    fb = fx * s.baseline
    white = gaussian(rng, (H, W))
    smooth = cv2.GaussianBlur(gaussian(rng, (H, W)), (0, 0), 2.0) * np.float32(2.0 * 2.0 * np.sqrt(np.pi))
    # sigma(z) is the sensor's total axial error; the disparity rounding below adds step^2 / 12 of variance
    step = z * z / (fb * s.subpixel)
    sigma = np.sqrt(np.maximum(depth_sigma(z, s) ** 2 - step * step / 12, (0.3 * depth_sigma(z, s)) ** 2))
    noisy = z + sigma.astype(np.float32) * (np.float32(0.7) * white + np.float32(0.7) * smooth)
    disp = np.round(fb / np.maximum(noisy, 0.1) * s.subpixel) / s.subpixel
    return np.where(z > 0, fb / np.maximum(disp, 1e-3), 0.0).astype(np.float32)


def sense_depth(
    rng: np.random.Generator,
    z: np.ndarray,
    fx: float,
    albedo_lum: np.ndarray,
    cos_inc: np.ndarray,
    s: DepthSensor = DepthSensor(),
) -> np.ndarray:
    """Noisy, quantised, holey float32 depth from the exact depth z (H, W)."""
    H, W = z.shape
    fb = fx * s.baseline
    out = axial_noise(rng, z, fx, s)
    drop = (z < s.min_depth) | (z > s.max_depth)
    drop |= projector_shadow(z, fb)
    zp = np.pad(z, 1, mode="edge")  # depth discontinuities: a jump to one of the 4-neighbours
    jump = np.maximum(
        np.maximum(np.abs(zp[1:-1, 2:] - z), np.abs(zp[1:-1, :-2] - z)),
        np.maximum(np.abs(zp[2:, 1:-1] - z), np.abs(zp[:-2, 1:-1] - z)),
    )
    band = cv2.dilate((jump > 0.04 * z).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    drop |= band & (rng.random((H, W), dtype=np.float32) < s.edge_drop)
    dark = np.clip((s.dark_albedo - albedo_lum) / s.dark_albedo, 0, 1) * 0.9
    glancing = np.clip((s.glancing_cos - np.abs(cos_inc)) / s.glancing_cos, 0, 1) * 0.8
    p = 1 - (1 - dark) * (1 - glancing)
    drop |= clumpy_uniform(rng, (H, W), 2.0) < p  # holes come in clumps, not as salt
    drop |= blobs(rng, H, W)
    out[drop] = 0.0
    return out


def projector_shadow(z: np.ndarray, fb: float, max_shift: int = 64) -> np.ndarray:
    """Pixels the projector cannot see, (H, W) bool; it sits fb / f to the camera's right (+x).

    The projector sees the point of pixel u at projector column u - d(u), d = fb / z; a pixel
    is shadowed when a pixel u + k to its right maps at or before it there, d(u + k) - d(u) >= k:
    shadows lie left of foreground objects, as in Kinect v1 images.
    """
    d = fb / np.maximum(z, 1e-3)
    shadow = np.zeros(z.shape, bool)
    for k in range(1, min(max_shift, int(np.ceil(d.max() - d.min())) + 1)):
        shadow[:, :-k] |= d[:, k:] - d[:, :-k] >= k
    return shadow


def blobs(rng: np.random.Generator, H: int, W: int) -> np.ndarray:
    mask = np.zeros((H, W), np.uint8)
    for _ in range(int(rng.poisson(3))):
        c = (int(rng.integers(W)), int(rng.integers(H)))
        axes = (int(rng.integers(2, 12)), int(rng.integers(2, 10)))
        cv2.ellipse(mask, c, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return mask.astype(bool)


@functools.cache
def vignette(H: int, W: int) -> np.ndarray:
    """(H, W) squared distance from the image centre, 1 at the corners."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    return ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / (W * W / 4 + H * H / 4)


def motion_kernel(rng: np.random.Generator, lo: int, hi: int) -> np.ndarray:
    """A normalised straight-streak blur kernel of lo to hi - 1 pixels (hand shake)."""
    n = int(rng.integers(lo, hi))
    k = np.zeros((n, n), np.float32)
    cv2.line(k, (0, int(rng.integers(n))), (n - 1, int(rng.integers(n))), 1.0, 1)
    return k / k.sum()


def sense_colour(rng: np.random.Generator, radiance: np.ndarray) -> np.ndarray:
    """uint8 BGR image from linear RGB radiance (H, W, 3)."""
    H, W, _ = radiance.shape
    lum = radiance[::4, ::4] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    exposure = float(rng.uniform(0.5, 0.8)) / max(float(np.percentile(lum, 95)), 1e-4)
    gain = (exposure * rng.uniform(0.9, 1.1, 3)).astype(np.float32)
    img = radiance * gain * (1 - float(rng.uniform(0.1, 0.35)) * vignette(H, W))[..., None]
    img = np.clip(img, 0, 1) ** np.float32(1 / 2.2)
    if rng.random() < 0.3:  # hand shake
        img = cv2.filter2D(img, -1, motion_kernel(rng, 3, 8))
    img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.5, 0.9)))
    sigma = np.float32(rng.uniform(0.004, 0.015))
    img += gaussian(rng, img.shape) * (sigma * np.sqrt(img + np.float32(0.02)))
    return np.ascontiguousarray(np.clip(img[..., ::-1] * 255 + 0.5, 0, 255).astype(np.uint8))
