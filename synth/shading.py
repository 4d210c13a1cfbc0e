"""Materials, textures, surface normals and lighting of the rendered scenes.

Materials are drawn from one distribution for every object whatever its class (so colour and
texture say nothing about the class); rooms draw their floor, wall and ceiling materials from
their own distributions. A material is a tileable procedural texture (plain, mottled noise,
wood grain, fabric weave, checker tiles, stripes, speckle, brushed metal) in linear RGB albedo,
a tile size in metres and a gloss. Lighting is Lambertian: an ambient term, a shadowed main
point light under the ceiling (shadow map rendered by ``a3d.synth.raycast``), fill point lights
and sometimes a directional "window" light, plus a Blinn-Phong highlight on glossy materials and
screen-space ambient occlusion from the depth map.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from a3d.synth.parts import CYL
from a3d.synth.raycast import PartArrays, RayGrid, cast

ROOM = 2  # part kind of the room box (seen from inside)
TEX = 128  # texture side (texels)
KINDS = ("plain", "mottled", "wood", "fabric", "checker", "stripes", "speckle", "metal")
FLOOR, CEILING, WALL = 0, 1, 2  # room surfaces


@dataclass(frozen=True)
class Materials:
    """M materials: ``texture`` (M, TEX, TEX, 3) float32 linear albedo, ``tile`` (M,) metres per
    texture repeat, ``gloss`` (M,) specular strength, ``kind`` (M,) index into KINDS."""

    texture: np.ndarray
    tile: np.ndarray
    gloss: np.ndarray
    kind: np.ndarray


def _noise(rng: np.random.Generator, beta: float, aniso: float = 1.0) -> np.ndarray:
    """Tileable 1/f^beta noise (TEX, TEX), zero mean, unit std; aniso > 1 stretches it along x."""
    f = np.fft.fftfreq(TEX)
    fy, fx = np.meshgrid(f, f / aniso, indexing="ij")
    amp = (fx * fx + fy * fy + 1e-4) ** (-beta / 2)
    amp[0, 0] = 0.0
    spec = amp * np.exp(2j * np.pi * rng.random((TEX, TEX)))
    out = np.fft.ifft2(spec).real
    return ((out - out.mean()) / (out.std() + 1e-9)).astype(np.float32)


def _hsv_colour(rng: np.random.Generator, sat: tuple[float, float], val: tuple[float, float]) -> np.ndarray:
    """A linear-RGB colour from a random hue and the given saturation and value ranges."""
    hsv = np.array([[[rng.uniform(0, 180), rng.uniform(*sat) * 255, rng.uniform(*val) * 255]]], np.float32)
    srgb = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32) / 255
    return srgb**2.2


def make_texture(rng: np.random.Generator, kind: str, base: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(TEX, TEX, 3) linear albedo of a texture kind in colours ``base`` and ``other``."""
    yy, xx = np.mgrid[0:TEX, 0:TEX].astype(np.float32) / TEX
    if kind == "plain":
        m = 1 + 0.03 * _noise(rng, 2.5)
        return base * m[..., None]
    if kind == "mottled":
        m = 1 + float(rng.uniform(0.08, 0.2)) * _noise(rng, float(rng.uniform(1.5, 2.5)))
        return base * m[..., None]
    if kind == "wood":
        n = int(rng.integers(3, 9))
        grain = np.sin(2 * np.pi * (n * yy + 0.5 * _noise(rng, 2.5, aniso=8.0) / 4)) * 0.5 + 0.5
        fine = 0.06 * _noise(rng, 1.0, aniso=16.0)
        return (base * (1 - 0.35 * grain[..., None]) * (1 + fine[..., None])).astype(np.float32)
    if kind == "fabric":
        n = int(rng.choice([16, 32, 64]))
        weave = np.sin(2 * np.pi * n * xx) * np.sin(2 * np.pi * n * yy)
        m = 1 + 0.08 * weave + 0.06 * _noise(rng, 1.5)
        return base * m[..., None]
    if kind == "checker":
        n = int(rng.choice([2, 4, 8]))
        sq = ((np.floor(xx * n) + np.floor(yy * n)) % 2)[..., None]
        grout = ((np.abs((xx * n) % 1 - 0.5) > 0.47) | (np.abs((yy * n) % 1 - 0.5) > 0.47))[..., None]
        out = base * (1 - sq) + other * sq
        out = np.where(grout, 0.5 * (base + other) * 0.7, out)
        return out * (1 + 0.04 * _noise(rng, 2.0))[..., None]
    if kind == "stripes":
        n = int(rng.choice([4, 8, 16]))
        s = (np.sin(2 * np.pi * n * xx) > float(rng.uniform(-0.5, 0.5)))[..., None]
        return np.where(s, base, other) * (1 + 0.03 * _noise(rng, 2.0))[..., None]
    if kind == "speckle":
        spots = cv2.GaussianBlur(rng.random((TEX, TEX)).astype(np.float32), (3, 3), 0.7)
        mix = (spots > float(rng.uniform(0.55, 0.7)))[..., None]
        return np.where(mix, other, base) * (1 + 0.1 * _noise(rng, 1.0))[..., None]
    grey = np.full(3, float(rng.uniform(0.1, 0.6)), np.float32) * (0.8 + 0.2 * base / (base.max() + 1e-6))
    return grey * (1 + 0.08 * _noise(rng, 1.0, aniso=30.0))[..., None]


def draw_materials(rng: np.random.Generator, n: int, surface: str = "object") -> Materials:
    """n materials for ``surface`` in "object", "floor", "wall", "ceiling" (the same draw for every class)."""
    kinds = {
        "object": (KINDS, [0.2, 0.18, 0.2, 0.14, 0.06, 0.08, 0.06, 0.08]),
        "floor": (("wood", "checker", "mottled", "fabric", "speckle"), [0.35, 0.2, 0.2, 0.15, 0.1]),
        "wall": (("plain", "mottled", "stripes", "fabric"), [0.5, 0.3, 0.1, 0.1]),
        "ceiling": (("plain", "mottled"), [0.7, 0.3]),
    }[surface]
    val = {"object": (0.08, 0.95), "floor": (0.15, 0.75), "wall": (0.55, 0.95), "ceiling": (0.75, 0.98)}[surface]
    sat = {"object": (0.0, 0.75), "floor": (0.0, 0.6), "wall": (0.0, 0.3), "ceiling": (0.0, 0.08)}[surface]
    tex, tile, gloss, kind = [], [], [], []
    for _ in range(n):
        k = str(rng.choice(kinds[0], p=kinds[1]))
        base = _hsv_colour(rng, sat, val)
        other = _hsv_colour(rng, sat, val) if rng.random() < 0.6 else base * float(rng.uniform(0.3, 0.7))
        tex.append(np.clip(make_texture(rng, k, base, other), 0.0, 1.0))
        tile.append(float(rng.uniform(0.25, 1.2)) if k not in ("fabric", "speckle") else float(rng.uniform(0.15, 0.5)))
        gloss.append(float(rng.choice([0.0, 0.0, rng.uniform(0.05, 0.3), 0.5 if k == "metal" else 0.1])))
        kind.append(KINDS.index(k))
    return Materials(np.stack(tex).astype(np.float32), np.array(tile, np.float32), np.array(gloss, np.float32),
                     np.array(kind, np.int64))


def concat_materials(*banks: Materials) -> Materials:
    return Materials(*(np.concatenate([getattr(b, f) for b in banks]) for f in ("texture", "tile", "gloss", "kind")))


# ----------------------------------------------------------------------------- surfaces


@dataclass(frozen=True)
class Surfaces:
    """Per-pixel hit geometry: tilt-frame ``point`` and unit ``normal`` (3, H, W) float32,
    texture coordinates ``uv`` (2, H, W) in metres, and ``face`` (H, W): the room surface
    (FLOOR, CEILING, WALL) for room pixels, else -1."""

    point: np.ndarray
    normal: np.ndarray
    uv: np.ndarray
    face: np.ndarray


def surfaces(grid: RayGrid, t: np.ndarray, part: np.ndarray, parts: PartArrays) -> Surfaces:
    """Normals and texture coordinates of the hit points (every pixel must hit some part)."""
    P = grid.points(t)
    kind = parts.kind[part]
    ca, sa = np.cos(parts.yaw).astype(np.float32)[part], np.sin(parts.yaw).astype(np.float32)[part]
    c = parts.centre.astype(np.float32)
    q0, q1, q2 = P[0] - c[part, 0], P[1] - c[part, 1], P[2] - c[part, 2]
    qx, qy, qz = ca * q0 - sa * q2, q1, sa * q0 + ca * q2
    half = parts.half.astype(np.float32)[part]  # (H, W, 3)
    rx, ry, rz = qx / half[..., 0], qy / half[..., 1], qz / half[..., 2]
    ax, ay, az = np.abs(rx), np.abs(ry), np.abs(rz)
    axis = np.where((ax >= ay) & (ax >= az), 0, np.where(ay >= az, 1, 2))
    rho = np.sqrt(rx * rx + rz * rz)
    is_cyl = kind == CYL
    axis = np.where(is_cyl, np.where(ay >= rho, 1, 3), axis)  # 3: cylinder side
    sign = np.where(kind == ROOM, -1.0, 1.0).astype(np.float32)
    n = np.zeros((3, *t.shape), np.float32)
    n[0] = np.where(axis == 0, np.sign(rx), 0) * sign
    n[1] = np.where(axis == 1, np.sign(ry), 0) * sign
    n[2] = np.where(axis == 2, np.sign(rz), 0) * sign
    side = axis == 3
    if side.any():
        gx, gz = rx / half[..., 0], rz / half[..., 2]
        norm = np.sqrt(gx * gx + gz * gz) + 1e-12
        n[0] = np.where(side, gx / norm, n[0])
        n[2] = np.where(side, gz / norm, n[2])
    nx = ca * n[0] + sa * n[2]  # back to the tilt frame: R_y(yaw)
    nz = -sa * n[0] + ca * n[2]
    normal = np.stack([nx, n[1], nz])
    radius = 0.5 * (half[..., 0] + half[..., 2])
    u = np.select([axis == 0, axis == 3], [qz, np.arctan2(rx, rz) * radius], qx)
    v = np.where(axis == 1, qz, qy)
    offset = (part.astype(np.float32) * 0.377) % 1.0
    uv = np.stack([u + offset, v + 2 * offset])
    face = np.where(kind == ROOM, np.select([(axis == 1) & (ry > 0), axis == 1], [FLOOR, CEILING], WALL), -1)
    return Surfaces(P, normal, uv, face)


def albedo(s: Surfaces, part: np.ndarray, parts: PartArrays, mats: Materials, room_faces: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear albedo: each part's material (the room's per face) sampled at its uv, tinted."""
    m = np.where(s.face >= 0, room_faces[np.maximum(s.face, 0)], parts.material[part])
    tile = mats.tile[m]
    iu = (np.mod(s.uv[0] / tile, 1.0) * TEX).astype(np.int64) % TEX
    iv = (np.mod(s.uv[1] / tile, 1.0) * TEX).astype(np.int64) % TEX
    return mats.texture[m, iv, iu] * parts.tint.astype(np.float32)[part]


# ----------------------------------------------------------------------------- lights


@dataclass(frozen=True)
class Lights:
    """Tilt-frame lights: ambient RGB; point lights (positions (L, 3), RGB powers (L, 3), the
    first one casting shadows); an optional directional light (unit direction it shines along, RGB)."""

    ambient: np.ndarray
    positions: np.ndarray
    powers: np.ndarray
    sun_dir: np.ndarray | None
    sun: np.ndarray | None


def draw_lights(rng: np.random.Generator, ceiling_y: float, room_corners: np.ndarray) -> Lights:
    """Ambient + 1-3 ceiling lights at random spots of the room (tilt frame), sometimes a sun."""
    tint = lambda: np.array([1.0, rng.uniform(0.85, 1.0), rng.uniform(0.65, 1.0)])[:: int(rng.choice([1, -1]))]  # noqa: E731
    n = int(rng.integers(1, 4))
    lo, hi = room_corners.min(axis=0), room_corners.max(axis=0)
    pos = []
    for _ in range(n):
        w = rng.dirichlet(np.ones(len(room_corners)) * 2)
        p = w @ room_corners
        pos.append([p[0], ceiling_y + float(rng.uniform(0.05, 0.5)), p[2]])
    pos_arr = np.clip(np.array(pos), [lo[0] + 0.1, -np.inf, lo[2] + 0.1], [hi[0] - 0.1, np.inf, hi[2] - 0.1])
    powers = np.array([tint() * rng.uniform(0.6, 1.4) * (1.0 if i == 0 else rng.uniform(0.2, 0.6)) for i in range(n)])
    ambient = tint() * rng.uniform(0.12, 0.35)
    sun_dir = sun = None
    if rng.random() < 0.3:
        d = np.array([rng.normal(), rng.uniform(0.3, 1.0), rng.normal()])
        sun_dir, sun = d / np.linalg.norm(d), tint() * rng.uniform(0.2, 0.6)
    return Lights(ambient, pos_arr, powers, sun_dir, sun)


_LIGHT_ROT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # view (x, y, z) -> tilt: z down
_SHADOW_SIZE, _SHADOW_TAN = 160, 3.0


def shadow_factor(points: np.ndarray, light: np.ndarray, parts: PartArrays, n_objects: int) -> np.ndarray:
    """(H, W) in [0, 1]: how much of the light reaches each point (1 = lit), by a shadow map.

    The map looks straight down from the light over a 143-degree field; points it does not
    cover count as lit. Four neighbouring map samples are compared and averaged (soft edges).
    """
    f = _SHADOW_SIZE / (2 * _SHADOW_TAN)
    c = (_SHADOW_SIZE - 1) / 2
    K = np.array([[f, 0, c], [0, f, c], [0, 0, 1.0]])
    grid = RayGrid.make(light, _LIGHT_ROT, K, (_SHADOW_SIZE, _SHADOW_SIZE))
    depth = cast(grid, parts, n_objects).t
    rel = points - light.astype(np.float32)[:, None, None]
    vz = rel[1]  # view z = tilt y (down)
    vx, vy = rel[0], -rel[2]
    ok = vz > 0.05
    safe = np.where(ok, vz, 1.0)
    u, v = f * vx / safe + c, f * vy / safe + c
    ok &= (u >= 0) & (u < _SHADOW_SIZE - 1) & (v >= 0) & (v < _SHADOW_SIZE - 1)
    lit = np.zeros(vz.shape, np.float32)
    u0, v0 = np.where(ok, u, 0).astype(np.int64), np.where(ok, v, 0).astype(np.int64)
    bias = 0.03 + 0.02 * vz
    for du in (0, 1):
        for dv in (0, 1):
            lit += (depth[v0 + dv, u0 + du] >= vz - bias).astype(np.float32)
    return np.where(ok, lit / 4, 1.0)


def illuminate(s: Surfaces, alb: np.ndarray, gloss: np.ndarray, lights: Lights, origin: np.ndarray,
               depth: np.ndarray, lit_main: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear radiance: albedo times (ambient + lights) plus highlights, with SSAO."""
    P, N = s.point, s.normal
    view = origin.astype(np.float32)[:, None, None] - P
    view /= np.linalg.norm(view, axis=0, keepdims=True) + 1e-9
    diffuse = np.zeros(alb.shape, np.float32)
    spec = np.zeros(alb.shape[:2], np.float32)
    sky = 0.85 - 0.15 * N[1]  # surfaces facing up (n_y = -1) get more ambient light
    for i, (pos, power) in enumerate(zip(lights.positions, lights.powers, strict=True)):
        L = pos.astype(np.float32)[:, None, None] - P
        d2 = np.sum(L * L, axis=0)
        L /= np.sqrt(d2)[None]
        ndl = np.maximum(np.sum(N * L, axis=0), 0) / (1 + d2 / 6.0) * 3.0
        if i == 0:
            ndl *= lit_main
        diffuse += ndl[..., None] * power.astype(np.float32)
        h = L + view
        h /= np.linalg.norm(h, axis=0, keepdims=True) + 1e-9
        spec += ndl * np.maximum(np.sum(N * h, axis=0), 0) ** 40
    if lights.sun_dir is not None:
        ndl = np.maximum(-np.tensordot(lights.sun_dir.astype(np.float32), N, axes=1), 0)
        diffuse += ndl[..., None] * lights.sun.astype(np.float32)
    z = np.where(np.isfinite(depth), depth, 10.0).astype(np.float32)
    blur = cv2.GaussianBlur(z, (0, 0), 9)
    ao = 1 - np.clip(2.5 * (z - blur) / np.maximum(blur, 0.5), 0, 0.45)
    ambient = (lights.ambient.astype(np.float32)[None, None] * (sky * ao)[..., None])
    return alb * (ambient + diffuse) + (gloss * spec)[..., None]


def tint_jitter(rng: np.random.Generator, n: int, spread: float = 0.06) -> np.ndarray:
    """(n, 3) per-part multiplicative colour jitter around 1 (class-blind)."""
    return np.clip(1 + rng.normal(0, spread, (n, 3)), 0.7, 1.3) * rng.uniform(0.85, 1.15, (n, 1))

