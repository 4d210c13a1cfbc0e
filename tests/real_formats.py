"""Write a3d-synth frames in real data sets' formats (TUM RGB-D, SUN RGB-D release and VoteNet
layouts), each written as the data set's own tools write it, for the source tests to read back;
and a3d-run on a source, for the tests that compare its detections between formats."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.structures.geometry import Intrinsics, box_corners_camera
from a3d.synth import SceneConfig, SynthFrame, generate_frame
from a3d.synth.cli import scaled_intrinsics

SIZE = (96, 128)
CONFIG = replace(SceneConfig(), image_size=SIZE, intrinsics=scaled_intrinsics(SIZE))
A = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # SUN depth frame from camera frame


def synth_frames(seeds: tuple[int, ...] = (3, 4)) -> list[SynthFrame]:
    return [generate_frame(seed, CONFIG) for seed in seeds]


def jpeg(color_bgr: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".jpg", color_bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return data.tobytes()


def png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image)
    assert ok
    return data.tobytes()


def R_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def sun_K(K: Intrinsics) -> np.ndarray:
    """SUN's camera matrix (1-based pixel coordinates) of a3d intrinsics."""
    return np.array([[K.fx, 0.0, K.cx + 1.0], [0.0, K.fy, K.cy + 1.0], [0.0, 0.0, 1.0]])


def sun_depth_png(millimetres: np.ndarray) -> bytes:
    """SUN's depth PNG: millimetres circularly shifted left by 3 bits (the reader shifts them back)."""
    mm = millimetres.astype(np.uint16)
    return png((mm << 3) | (mm >> 13))


# ----------------------------------------------------------------------------- TUM RGB-D


def write_tum(folder: Path, frames: list[SynthFrame], stamps: list[float]) -> list[np.ndarray]:
    """A TUM sequence (rgb/, depth/ PNGs, rgb.txt, depth.txt, depth 3 ms after colour); returns
    each frame's depth as the reader must give it (float32 of 5000 units per metre)."""
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    rgb_lines, depth_lines, depths = ["# color images", "# timestamp filename"], ["# depth maps"], []
    for frame, t in zip(frames, stamps, strict=True):
        units = np.rint(frame.depth.astype(np.float64) * 5000).astype(np.uint16)
        (folder / "rgb" / f"{t:.6f}.png").write_bytes(png(frame.color))
        (folder / "depth" / f"{t + 0.003:.6f}.png").write_bytes(png(units))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t + 0.003:.6f} depth/{t + 0.003:.6f}.png")
        depths.append(units.astype(np.float32) / np.float32(5000))
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    return depths


def write_tum_trajectory(folder: Path, stamps: list[float], poses: list[np.ndarray]) -> None:
    """``groundtruth.txt``: one ``timestamp tx ty tz qx qy qz qw`` line per camera-to-world pose."""
    lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for t, T in zip(stamps, poses, strict=True):
        q = quaternion_of(T[:3, :3])
        lines.append(f"{t:.4f} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q)))
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")


def quaternion_of(R: np.ndarray) -> np.ndarray:
    """(qx, qy, qz, qw) of a rotation with a trace > -1 (what the tests' poses have)."""
    w = np.sqrt(1.0 + np.trace(R)) / 2.0
    return np.array(
        [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w]
    )


# ----------------------------------------------------------------------------- 7-Scenes


def write_seven_scenes(folder: Path, frames: list[SynthFrame], poses: list[np.ndarray]) -> list[np.ndarray]:
    """A 7-Scenes-style sequence (camera-intrinsics.txt, frame-NNNNNN.color.png / .depth.png in
    millimetres with 65535 where there is no depth / .pose.txt); returns each frame's depth as the
    reader must give it."""
    folder.mkdir(parents=True)
    K = frames[0].intrinsics.matrix()
    (folder / "camera-intrinsics.txt").write_text("\n".join(" ".join(f"{v:.6f}" for v in row) for row in K))
    depths = []
    for i, (frame, T) in enumerate(zip(frames, poses, strict=True)):
        mm = np.rint(frame.depth.astype(np.float64) * 1000).astype(np.uint16)
        mm[mm == 0] = 65535
        (folder / f"frame-{i:06d}.color.png").write_bytes(png(frame.color))
        (folder / f"frame-{i:06d}.depth.png").write_bytes(png(mm))
        (folder / f"frame-{i:06d}.pose.txt").write_text(
            "\n".join(" ".join(f"{v:.9e}" for v in row) for row in T)
        )
        depths.append(np.where(mm == 65535, 0, mm).astype(np.float32) / np.float32(1000))
    return depths


# ----------------------------------------------------------------------------- SUN RGB-D release


def write_sun_release_frame(
    folder: Path, color_jpeg: bytes, millimetres: np.ndarray, K: Intrinsics, E: np.ndarray | None, objects=()
) -> None:
    """One release frame folder: image/, depth/ (and depth_bfx/ the same), intrinsics.txt,
    extrinsics/ (E as 3 x 4, an older file first), annotation3Dfinal/index.json and a fullres/."""
    name = folder.name
    for sub in ("image", "depth", "depth_bfx", "fullres", "annotation3Dfinal"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    (folder / "image" / f"{name}.jpg").write_bytes(color_jpeg)
    (folder / "depth" / f"{name}.png").write_bytes(sun_depth_png(millimetres))
    (folder / "depth_bfx" / f"{name}.png").write_bytes(sun_depth_png(millimetres))
    (folder / "fullres" / f"{name}.jpg").write_bytes(color_jpeg)
    np.savetxt(folder / "intrinsics.txt", sun_K(K), fmt="%.17g")
    if E is not None:
        (folder / "extrinsics").mkdir()
        np.savetxt(folder / "extrinsics" / "20150101000000.txt", np.eye(3, 4), fmt="%.17g")
        np.savetxt(
            folder / "extrinsics" / "20150118235401.txt", np.hstack([E, np.zeros((3, 1))]), fmt="%.17g"
        )
    document = {"name": name, "objects": [None, *objects]}
    (folder / "annotation3Dfinal" / "index.json").write_text(json.dumps(document))


def footprint_object(name: str, points_xz: list[tuple[float, float]], ymin: float, ymax: float) -> dict:
    X, Z = zip(*points_xz, strict=True)
    return {
        "name": name,
        "polygon": [{"X": list(X), "Z": list(Z), "Ymin": ymin, "Ymax": ymax, "rectangle": True}],
    }


# ----------------------------------------------------------------------------- VoteNet layout


def write_votenet_frame(
    root: Path,
    index: int,
    color_jpeg: bytes,
    points_u: np.ndarray,
    Rtilt_sun: np.ndarray,
    K: Intrinsics,
    label_lines: list[str] | None,
) -> None:
    """image/%06d.jpg, depth/%06d.mat ('instance', N x 6), calib/%06d.txt (Rtilt, K column-major)
    and label/%06d.txt, as extract_rgbd_data_v2.m writes them."""
    scipy_io = pytest.importorskip("scipy.io")
    for sub in ("image", "depth", "calib", "label"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    (root / "image" / f"{index:06d}.jpg").write_bytes(color_jpeg)
    scipy_io.savemat(root / "depth" / f"{index:06d}.mat", {"instance": points_u})
    calib = [" ".join(f"{v:.17g}" for v in M.ravel(order="F")) for M in (Rtilt_sun, sun_K(K))]
    (root / "calib" / f"{index:06d}.txt").write_text("\n".join(calib) + "\n")
    if label_lines is not None:
        (root / "label" / f"{index:06d}.txt").write_text("".join(line + "\n" for line in label_lines))


def upright_cloud(
    depth: np.ndarray, color_bgr: np.ndarray, K: Intrinsics, Rtilt_sun: np.ndarray
) -> np.ndarray:
    """The dense cloud read3dPoints makes of a depth map: every valid pixel (1-based column i,
    row j) at x = (i - cx) z / fx, y = (j - cy) z / fy in SUN's K, to SUN's depth frame (x, z, -y),
    then upright (Rtilt_sun); with the pixel's colour in [0, 1]."""
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols].astype(np.float64)
    Ks = sun_K(K)
    camera = np.column_stack([(cols + 1 - Ks[0, 2]) * z / Ks[0, 0], (rows + 1 - Ks[1, 2]) * z / Ks[1, 1], z])
    upright = camera @ A.T @ Rtilt_sun.T
    return np.column_stack([upright, color_bgr[rows, cols, ::-1] / 255.0])


# ----------------------------------------------------------------------------- a3d-run


def run_detections(source: Path, model: Path, output: Path, *extra: str) -> dict[str, object]:
    """a3d-run on ``source`` with ``model`` (exit 0 asserted): frame name -> its detections line."""
    argv = [str(source), "--model", str(model), "--output", str(output), "--headless", "--threads", "1"]
    assert run_cli.main([*argv, *extra]) == 0
    return {line.frame: line for line in read_detections(output)}


def assert_same_detections(got: dict, expected: dict, atol: float = 1e-6) -> None:
    """The same frames with the same detections (classes, scores, boxes, R_tilt) to ``atol``."""
    assert sorted(got) == sorted(expected)
    assert sum(len(line.scores) for line in expected.values()) > 0  # something was compared
    for name, line in expected.items():
        other = got[name]
        np.testing.assert_array_equal(other.class_ids, line.class_ids, err_msg=name)
        for field in ("scores", "boxes2d", "boxes3d", "R_tilt"):
            np.testing.assert_allclose(getattr(other, field), getattr(line, field), atol=atol, err_msg=name)


def sun_name(cls: str) -> str:
    return {"television": "tv"}.get(cls, cls.replace(" ", "_"))


def footprints_of(frame: SynthFrame, E: np.ndarray) -> list[dict]:
    """The frame's ground truth as release footprints: lower-face corners 0, 1, 2 and both heights in w."""
    corners_w = box_corners_camera(frame.gt.boxes3d, frame.R_tilt) @ E.T
    return [
        footprint_object(sun_name(cls), [(c[i, 0], c[i, 2]) for i in range(3)], c[4, 1], c[0, 1])
        for cls, c in zip(frame.gt.classes, corners_w, strict=True)
    ]


def labels_of(frame: SynthFrame, Rtilt_sun: np.ndarray) -> list[str]:
    """The frame's ground truth as VoteNet label lines, made as readframeSUNRGBD + extract_rgbd_data_v2
    make them (the 3D numbers printed with %f, 6 decimals)."""
    lines = []
    corners_u = box_corners_camera(frame.gt.boxes3d, frame.R_tilt) @ A.T @ Rtilt_sun.T
    for cls, c, b2 in zip(frame.gt.classes, corners_u, frame.gt.boxes2d_visible, strict=True):
        centre = c.mean(axis=0)
        hx, hy = np.linalg.norm(c[1] - c[0]) / 2, np.linalg.norm(c[2] - c[1]) / 2
        hz = abs(c[4, 2] - c[0, 2]) / 2
        o = (c[0, :2] + c[1, :2]) / 2 - centre[:2]
        o = o / np.linalg.norm(o)
        box2d = [b2[0] + 1, b2[1] + 1, b2[2] - b2[0], b2[3] - b2[1]]
        numbers = " ".join(f"{v:f}" for v in (*centre, hx, hy, hz, *o))
        lines.append(f"{sun_name(cls)} {' '.join(f'{v:g}' for v in box2d)} {numbers}")
    return lines


def sun_intrinsics(frame: SynthFrame) -> Intrinsics:
    """What a3d reads back from SUN's K of the frame's intrinsics (cx + 1 - 1 in floating point)."""
    K = frame.intrinsics
    return Intrinsics(K.fx, K.fy, (K.cx + 1.0) - 1.0, (K.cy + 1.0) - 1.0)
