"""Materials, textures, surface normals and lighting of the rendered scenes.

Materials are drawn from one distribution for every object whatever its class (so colour and
texture say nothing about the class; ``a3d.synth.appearance`` optionally ties them); rooms draw
their floor, wall and ceiling materials from their own distributions. A material is a tileable
procedural texture (plain, mottled noise, wood grain, fabric weave, checker tiles, stripes,
speckle, brushed metal) in linear RGB albedo, a tile size in metres and a gloss. Lighting is
Lambertian: an ambient term, a shadowed main point light under the ceiling (shadow map rendered
by ``a3d.synth.raycast``), fill point lights and sometimes a directional "window" light, plus a
Blinn-Phong highlight on glossy materials and screen-space ambient occlusion from the depth map.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from a3d.synth.parts import CYL
from a3d.synth.raycast import PartArrays, RayGrid, cast

ROOM = 2  # part kind of the room box (seen from inside)
TEX = 128  # texture side (texels)
MIP_SIGMA = (0.0, 1.0, 2.0, 4.0)  # blur (texels) of the texture levels chosen by pixel footprint
MIP_LEVELS = len(MIP_SIGMA)
KINDS = ("plain", "mottled", "wood", "fabric", "checker", "stripes", "speckle", "metal")
FLOOR, CEILING, WALL = 0, 1, 2  # room surfaces


@dataclass(frozen=True)
class Materials:
    """M materials: ``texture`` (M, MIP_LEVELS, TEX, TEX, 3) float32 linear albedo (level k
    blurred by MIP_SIGMA[k] texels, for surfaces seen from afar), ``tile`` (M,) metres per texture
    repeat, ``gloss`` (M,) specular strength, ``kind`` (M,) index into KINDS."""

    texture: np.ndarray
    tile: np.ndarray
    gloss: np.ndarray
    kind: np.ndarray


@functools.cache
def _noise_bank(beta: float, aniso: float) -> np.ndarray:
    """(4, TEX, TEX) tileable 1/f^beta noise fields, zero mean, unit std, stretched ``aniso``
    times along x; made once per process from a fixed seed (so frames stay deterministic)."""
    rng = np.random.default_rng(round(beta * 100 + aniso))
    f = np.fft.fftfreq(TEX)
    fy, fx = np.meshgrid(f, f / aniso, indexing="ij")
    amp = (fx * fx + fy * fy + 1e-4) ** (-beta / 2)
    amp[0, 0] = 0.0
    out = np.fft.ifft2(amp * np.exp(2j * np.pi * rng.random((4, TEX, TEX))), axes=(1, 2)).real
    out -= out.mean(axis=(1, 2), keepdims=True)
    return (out / out.std(axis=(1, 2), keepdims=True)).astype(np.float32)


def _noise(rng: np.random.Generator, beta: float, aniso: float = 1.0) -> np.ndarray:
    """A random tileable noise field (TEX, TEX): a bank field, shifted and sign-flipped at random."""
    bank = _noise_bank(beta, aniso)
    field = np.roll(
        bank[int(rng.integers(len(bank)))], (int(rng.integers(TEX)), int(rng.integers(TEX))), axis=(0, 1)
    )
    return field if rng.random() < 0.5 else -field


def _hsv_colour(
    rng: np.random.Generator,
    sat: tuple[float, float],
    val: tuple[float, float],
    hue: tuple[float, float] = (0.0, 180.0),
) -> np.ndarray:
    """A linear-RGB colour from hue, saturation and value ranges (OpenCV's 0-180 hue; saturation
    skewed low, as in most furnishings)."""
    s = sat[0] + (sat[1] - sat[0]) * rng.random() ** 2
    hsv = np.array([[[rng.uniform(*hue), s * 255, rng.uniform(*val) * 255]]], np.float32)
    srgb = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32) / 255
    return srgb**2.2


def make_texture(rng: np.random.Generator, kind: str, base: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(TEX, TEX, 3) linear albedo of a texture kind in colours ``base`` and ``other``."""
    yy, xx = np.mgrid[0:TEX, 0:TEX].astype(np.float32) / TEX
    if kind == "plain":
        m = 1 + 0.03 * _noise(rng, 2.5)
        return base * m[..., None]
    if kind == "mottled":
        m = 1 + float(rng.uniform(0.08, 0.2)) * _noise(rng, float(rng.choice([1.5, 2.0, 2.5])))
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


def _mip_levels(texture: np.ndarray) -> np.ndarray:
    """(MIP_LEVELS, TEX, TEX, 3) copies of a tileable texture, blurred with wrap-around."""
    pad = 12
    wrapped = np.pad(texture, ((pad, pad), (pad, pad), (0, 0)), mode="wrap")
    levels = [texture] + [cv2.GaussianBlur(wrapped, (0, 0), sg)[pad:-pad, pad:-pad] for sg in MIP_SIGMA[1:]]
    return np.stack(levels)


def draw_materials(rng: np.random.Generator, n: int, surface: str = "object") -> Materials:
    """n materials for ``surface`` in "object", "floor", "wall", "ceiling" (the same draw for every class)."""
    kinds = {
        "object": (KINDS, [0.2, 0.18, 0.2, 0.14, 0.06, 0.08, 0.06, 0.08]),
        "floor": (("wood", "checker", "mottled", "fabric", "speckle"), [0.35, 0.2, 0.2, 0.15, 0.1]),
        "wall": (("plain", "mottled", "stripes", "fabric"), [0.5, 0.3, 0.1, 0.1]),
        "ceiling": (("plain", "mottled"), [0.7, 0.3]),
    }[surface]
    val = {"object": (0.08, 0.95), "floor": (0.15, 0.75), "wall": (0.55, 0.95), "ceiling": (0.75, 0.98)}[
        surface
    ]
    sat = {"object": (0.0, 0.75), "floor": (0.0, 0.6), "wall": (0.0, 0.3), "ceiling": (0.0, 0.08)}[surface]
    drawn = []
    for _ in range(n):
        k = str(rng.choice(kinds[0], p=kinds[1]))
        texture, tile = material_texture(rng, k, sat, val)
        gloss = float(rng.choice([0.0, 0.0, rng.uniform(0.05, 0.3), 0.5 if k == "metal" else 0.1]))
        drawn.append((texture, tile, gloss, k))
    return stack_materials(drawn)


def material_texture(
    rng: np.random.Generator,
    kind: str,
    sat: tuple[float, float],
    val: tuple[float, float],
    hue: tuple[float, float] = (0.0, 180.0),
) -> tuple[np.ndarray, float]:
    """Texture levels (MIP_LEVELS, TEX, TEX, 3) and tile size (metres) of one material of a
    texture kind, in two colours drawn from the hue, saturation and value ranges."""
    base = _hsv_colour(rng, sat, val, hue)
    other = _hsv_colour(rng, sat, val, hue) if rng.random() < 0.6 else base * float(rng.uniform(0.3, 0.7))
    texture = _mip_levels(np.clip(make_texture(rng, kind, base, other), 0.0, 1.0))
    fine = kind in ("fabric", "speckle")
    tile = float(rng.uniform(0.15, 0.5)) if fine else float(rng.uniform(0.25, 1.2))
    return texture, tile


def stack_materials(drawn: list[tuple[np.ndarray, float, float, str]]) -> Materials:
    """Materials from (texture levels, tile, gloss, kind name) tuples."""
    texture, tile, gloss, kind = zip(*drawn, strict=True)
    return Materials(
        np.stack(texture).astype(np.float32),
        np.array(tile, np.float32),
        np.array(gloss, np.float32),
        np.array([KINDS.index(k) for k in kind], np.int64),
    )


def concat_materials(*banks: Materials) -> Materials:
    return Materials(
        *(np.concatenate([getattr(b, f) for b in banks]) for f in ("texture", "tile", "gloss", "kind"))
    )


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
    """Normals and texture coordinates of the hit points (every pixel must hit some part).

    In the part's frame the hit point q lies on its surface: on a cuboid the face is the axis
    where |q| / half is largest (1); on a cylinder the cap if |q_y| / half_y >= the radial
    distance, else the side; the room box (seen from inside) has inward normals.
    """
    f32 = np.float32
    P = grid.points(t)
    flat = part.ravel()
    shape = t.shape

    def per_pixel(values: np.ndarray) -> np.ndarray:
        return np.take(np.asarray(values, f32), flat).reshape(shape)

    ca, sa = per_pixel(np.cos(parts.yaw)), per_pixel(np.sin(parts.yaw))
    q0, q1, q2 = (P[k] - per_pixel(parts.centre[:, k]) for k in range(3))
    qx, qy, qz = ca * q0 - sa * q2, q1, sa * q0 + ca * q2
    rx, ry, rz = (
        qx / per_pixel(parts.half[:, 0]),
        qy / per_pixel(parts.half[:, 1]),
        qz / per_pixel(parts.half[:, 2]),
    )
    kind = np.take(parts.kind, flat).reshape(shape)
    ax, ay, az = np.abs(rx), np.abs(ry), np.abs(rz)
    rho = np.sqrt(rx * rx + rz * rz)
    is_cyl = kind == CYL
    on_y = np.where(is_cyl, ay >= rho, (ay >= ax) & (ay >= az))
    on_x = ~is_cyl & ~on_y & (ax >= az)
    on_z = ~is_cyl & ~on_y & ~on_x
    side = is_cyl & ~on_y
    inward = np.where(kind == ROOM, f32(-1), f32(1))
    inv = f32(1) / (rho + f32(1e-12))
    nx = np.where(on_x, np.sign(rx) * inward, np.where(side, rx * inv, f32(0)))
    nz = np.where(on_z, np.sign(rz) * inward, np.where(side, rz * inv, f32(0)))
    ny = np.where(on_y, np.sign(ry) * inward, f32(0))
    normal = np.stack([ca * nx + sa * nz, ny, -sa * nx + ca * nz])  # back to the tilt frame: R_y(yaw)
    if side.any():  # arc length around the cylinder
        radius = 0.5 * (per_pixel(parts.half[:, 0]) + per_pixel(parts.half[:, 2]))
        qx = np.where(side, np.arctan2(rx, rz) * radius, qx)
    u = np.where(on_x, qz, qx)
    v = np.where(on_y, qz, qy)
    offset = per_pixel(np.arange(len(parts)) * 0.377 % 1.0)
    uv = np.stack([u + offset, v + 2 * offset])
    face = np.where(kind == ROOM, np.where(on_y, np.where(ry > 0, FLOOR, CEILING), WALL), -1)
    return Surfaces(P, normal, uv, face)


def albedo(
    s: Surfaces,
    part: np.ndarray,
    parts: PartArrays,
    mats: Materials,
    room_faces: np.ndarray,
    footprint: np.ndarray,
) -> np.ndarray:
    """(H, W, 3) linear albedo: each part's material (the room's per face) sampled at its uv, tinted.

    ``footprint`` (H, W) is the size of a pixel on the surface (metres); the texture level
    whose blur matches the texels per pixel is used, which avoids moire on distant surfaces.
    """
    m = np.where(s.face >= 0, room_faces[np.maximum(s.face, 0)], np.take(parts.material, part))
    texels = (TEX / mats.tile).astype(np.float32)[m]  # texels per metre
    level = np.searchsorted(np.array([1.5, 3.0, 6.0], np.float32), footprint * texels)
    iu = (s.uv[0] * texels).astype(np.int64) % TEX
    iv = (s.uv[1] * texels).astype(np.int64) % TEX
    flat = ((m * MIP_LEVELS + level) * TEX + iv) * TEX + iu
    tex = mats.texture.reshape(-1, 3)
    return np.take(tex, flat, axis=0) * np.take(parts.tint.astype(np.float32), part, axis=0)


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

    def tint():
        return np.array([1.0, rng.uniform(0.85, 1.0), rng.uniform(0.65, 1.0)])[:: int(rng.choice([1, -1]))]

    n = int(rng.integers(1, 4))
    lo, hi = room_corners.min(axis=0), room_corners.max(axis=0)
    pos = []
    for _ in range(n):
        w = rng.dirichlet(np.ones(len(room_corners)) * 2)
        p = w @ room_corners
        pos.append([p[0], ceiling_y + float(rng.uniform(0.05, 0.3)), p[2]])
    pos_arr = np.clip(np.array(pos), [lo[0] + 0.1, -np.inf, lo[2] + 0.1], [hi[0] - 0.1, np.inf, hi[2] - 0.1])
    powers = np.array(
        [tint() * rng.uniform(0.6, 1.4) * (1.0 if i == 0 else rng.uniform(0.2, 0.6)) for i in range(n)]
    )
    ambient = tint() * rng.uniform(0.12, 0.35)
    sun_dir = sun = None
    if rng.random() < 0.3:
        d = np.array([rng.normal(), rng.uniform(0.3, 1.0), rng.normal()])
        sun_dir, sun = d / np.linalg.norm(d), tint() * rng.uniform(0.2, 0.6)
    return Lights(ambient, pos_arr, powers, sun_dir, sun)


_LIGHT_ROT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # view (x, y, z) -> tilt: z down
_SHADOW_SIZE, _SHADOW_TAN = 256, 2.5


def shadow_factor(
    points: np.ndarray,
    light: np.ndarray,
    parts: PartArrays,
    n_objects: int,
    rot: np.ndarray = _LIGHT_ROT,
    tan: float = _SHADOW_TAN,
    size: int = _SHADOW_SIZE,
    bias: tuple[float, float] = (0.03, 0.02),
) -> np.ndarray:
    """(H, W) in [0, 1]: how much of the light reaches each point (1 = lit), by a shadow map.

    The map looks from the light along ``rot``'s third column (default straight down) over a
    field of half-width ``tan`` (default 136 degrees across); points it does not cover count as
    lit. The four nearest map samples are compared (depth bias ``bias[0] + bias[1] * depth``)
    and their results bilinearly weighted, then blurred a little (soft edges).
    """
    f = size / (2 * tan)
    c = (size - 1) / 2
    K = np.array([[f, 0, c], [0, f, c], [0, 0, 1.0]])
    grid = RayGrid.make(light, rot, K, (size, size))
    depth = cast(grid, parts, n_objects).t
    rel = points - light.astype(np.float32)[:, None, None]
    r = rot.astype(np.float32)
    vx, vy, vz = (r[0, k] * rel[0] + r[1, k] * rel[1] + r[2, k] * rel[2] for k in range(3))  # view frame
    ok = vz > 0.05
    safe = np.where(ok, vz, 1.0)
    u, v = f * vx / safe + c, f * vy / safe + c
    ok &= (u >= 0) & (u < size - 1) & (v >= 0) & (v < size - 1)
    fu_, fv_ = np.where(ok, u, 0), np.where(ok, v, 0)
    u0, v0 = fu_.astype(np.int64), fv_.astype(np.int64)
    wu, wv = (fu_ - u0).astype(np.float32), (fv_ - v0).astype(np.float32)
    limit = vz - (bias[0] + bias[1] * vz)  # depth bias against self-shadowing
    lit = np.zeros(vz.shape, np.float32)
    for du, dv, w in (
        (0, 0, (1 - wu) * (1 - wv)),
        (1, 0, wu * (1 - wv)),
        (0, 1, (1 - wu) * wv),
        (1, 1, wu * wv),
    ):
        lit += w * (depth[v0 + dv, u0 + du] >= limit)
    lit = cv2.GaussianBlur(lit, (0, 0), 1.5)  # soft shadow edges
    return np.where(ok, lit, np.float32(1))


def sun_shadow(
    points: np.ndarray,
    direction: np.ndarray,
    parts: PartArrays,
    n_objects: int,
    centre: np.ndarray,
    radius: float,
) -> np.ndarray:
    """(H, W) in [0, 1]: how much of a directional light shining along ``direction`` reaches each
    point; its shadow map looks along it from 60 m away (nearly parallel rays) over the sphere of
    ``radius`` about ``centre`` (the room), at 512 x 512."""
    d = direction / np.linalg.norm(direction)
    x = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    rot = np.column_stack([x, np.cross(d, x), d])
    distance = 60.0
    return shadow_factor(
        points, centre - distance * d, parts, n_objects, rot, radius / distance, 512, (0.04, 0.0)
    )


def ambient_occlusion(depth: np.ndarray) -> np.ndarray:
    """(H, W) ambient-occlusion factor in [0.55, 1]: darker where a pixel lies behind its
    neighbourhood (unsharp-masked depth, computed at quarter resolution)."""
    H, W = depth.shape
    z = np.where(np.isfinite(depth), depth, 10.0).astype(np.float32)
    small = cv2.resize(z, (max(W // 4, 1), max(H // 4, 1)), interpolation=cv2.INTER_AREA)
    blur = cv2.resize(cv2.GaussianBlur(small, (0, 0), 2.5), (W, H), interpolation=cv2.INTER_LINEAR)
    return 1 - np.clip(2.5 * (z - blur) / np.maximum(blur, 0.5), 0, 0.45)


def illuminate(
    s: Surfaces,
    alb: np.ndarray,
    gloss: np.ndarray,
    lights: Lights,
    depth: np.ndarray,
    lit_main: np.ndarray,
    lit_sun: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W, 3) linear radiance seen from a camera at the tilt-frame origin: albedo times
    (occluded ambient + lights with distance falloff) plus a highlight of the main light; the
    directional light is shadowed by ``lit_sun`` when given."""
    f32 = np.float32
    (px, py, pz), (nx, ny, nz) = s.point, s.normal
    inv_v = f32(1) / np.sqrt(px * px + py * py + pz * pz)
    irradiance = []
    spec = None
    for i, pos in enumerate(lights.positions.astype(f32)):
        lx, ly, lz = pos[0] - px, pos[1] - py, pos[2] - pz
        d2 = lx * lx + ly * ly + lz * lz
        inv_d = f32(1) / np.sqrt(d2)
        ndl = np.maximum((nx * lx + ny * ly + nz * lz) * inv_d, f32(0)) * (f32(3) / (f32(1) + d2 / f32(6)))
        if i == 0:
            ndl *= lit_main
            hx, hy, hz = lx * inv_d - px * inv_v, ly * inv_d - py * inv_v, lz * inv_d - pz * inv_v
            nh = np.maximum(nx * hx + ny * hy + nz * hz, f32(0)) / np.sqrt(
                hx * hx + hy * hy + hz * hz + f32(1e-12)
            )
            nh8 = ((nh * nh) ** 2) ** 2
            spec = ndl * ((nh8 * nh8) ** 2 * nh8)  # (n.h)^40
        irradiance.append(ndl)
    powers = lights.powers.astype(f32)
    if lights.sun_dir is not None:
        d = lights.sun_dir.astype(f32)
        sun = np.maximum(-(d[0] * nx + d[1] * ny + d[2] * nz), f32(0))
        irradiance.append(sun if lit_sun is None else sun * lit_sun)
        powers = np.vstack([powers, lights.sun.astype(f32)])
    sky = (f32(0.85) - f32(0.15) * ny) * ambient_occlusion(
        depth
    )  # surfaces facing up (n_y = -1) get more ambient light
    ambient = lights.ambient.astype(f32)
    light = [
        sum((p[c] * e for p, e in zip(powers, irradiance, strict=True)), sky * ambient[c]) for c in range(3)
    ]
    return alb * np.stack(light, axis=-1) + (gloss * spec)[..., None]


def tint_jitter(rng: np.random.Generator, n: int, spread: float = 0.06) -> np.ndarray:
    """(n, 3) per-part multiplicative colour jitter around 1 (class-blind)."""
    return np.clip(1 + rng.normal(0, spread, (n, 3)), 0.7, 1.3) * rng.uniform(0.85, 1.15, (n, 1))
