"""A camera's pose from image features matched to earlier frames', where depth odometry loses it.

Why: frame-to-model odometry (a3d.runtime.mapping.odometry) follows a camera that moves a few
centimetres between frames. Snapshots a metre apart, a stretch a recording dropped, or a robot
turning fast leave it nothing to slide into. Image features still match across such a jump: each
keyframe's ORB features, lifted by its own depth into the model's frame, give a new frame a pose
by PnP with RANSAC (OpenCV), as a visual SLAM system relocalises. The tracker then aligns the
frame on the depth from that pose and keeps it only where the depth agrees, as any frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.structures.geometry import Intrinsics, backproject, project_points
from a3d.runtime.structures.pose import invert_pose, make_pose, rigid_fit, rotation_deg, transform_points


@dataclass(frozen=True)
class FeatureConfig:
    """``features``: ORB keypoints a frame; ``ratio``: Lowe's test, a match kept where its best distance is
    under this share of the second best; ``reprojection_px``: RANSAC's inlier distances, a pose each
    (which suits depends on the camera and the room: the depth chooses); ``min_inliers``: the fewest
    inliers a pose is taken from; ``fit_m``: a match further than this from the rigid fit of the
    frame's depth to the keyframe's is dropped; ``keyframe_m`` / ``keyframe_deg``: a tracked frame
    becomes a keyframe once this far from the last one."""

    features: int = 2000
    ratio: float = 0.75
    reprojection_px: tuple[float, ...] = (2.0, 3.0, 5.0, 8.0)
    min_inliers: int = 30
    fit_m: float = 0.05
    keyframe_m: float = 0.2
    keyframe_deg: float = 10.0


@dataclass(frozen=True)
class Keyframe:
    """One keyframe's features with depth: descriptors (N, 32) uint8 and their points (N, 3) in
    the model's frame, and the keyframe's pose (camera to model)."""

    descriptors: np.ndarray
    points: np.ndarray
    pose: np.ndarray


@dataclass(frozen=True)
class Located:
    """The poses ``FeatureMap.locate`` finds for a frame: camera to model (4, 4), one per RANSAC
    threshold and one per rigid fit to the frame's depth, for the depth to choose among; the
    most RANSAC inliers, and the keyframe (index) they matched."""

    poses: tuple[np.ndarray, ...]
    inliers: int
    keyframe: int


class FeatureMap:
    """The keyframes of one camera's recording (module docstring)."""

    def __init__(self, intrinsics: Intrinsics, config: FeatureConfig = FeatureConfig()) -> None:
        self.intrinsics, self.config = intrinsics, config
        self.keyframes: list[Keyframe] = []
        self._orb = cv2.ORB_create(config.features)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self._K = intrinsics.matrix()

    def add(self, gray: np.ndarray, depth: np.ndarray, pose: np.ndarray) -> bool:
        """Keep the frame as a keyframe if it is the first or far enough from the last one
        (``FeatureConfig``); whether it was kept."""
        if self.keyframes and not _moved(self.keyframes[-1].pose, pose, self.config):
            return False
        keypoints, descriptors = self._orb.detectAndCompute(gray, None)
        if descriptors is None:
            return False
        camera = self._lifted(np.array([k.pt for k in keypoints], np.float64), depth)
        held = np.isfinite(camera[:, 2])
        if held.sum() < self.config.min_inliers:
            return False
        self.keyframes.append(Keyframe(descriptors[held], transform_points(pose, camera[held]), pose.copy()))
        return True

    def locate(self, gray: np.ndarray, depth: np.ndarray) -> Located | None:
        """Candidate poses of the camera in the model's frame from the keyframe whose features
        it matches most (Lowe's ratio test): PnP with RANSAC at each ``reprojection_px``, and
        for each the rigid fit of the frame's own depth at the matches RANSAC kept (exact where
        the depth is, tens of centimetres off where features sit on depth edges, as a Kinect's
        do); None where the keyframe gives fewer than ``min_inliers``."""
        keypoints, descriptors = self._orb.detectAndCompute(gray, None)
        if descriptors is None or not self.keyframes:
            return None
        ranked = []
        for index, keyframe in enumerate(self.keyframes):
            pairs = self._matcher.knnMatch(descriptors, keyframe.descriptors, k=2)
            good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < self.config.ratio * p[1].distance]
            ranked.append((len(good), index, good))
        count, index, good = max(ranked, key=lambda r: r[0])
        if count < self.config.min_inliers:
            return None
        world = self.keyframes[index].points[[m.trainIdx for m in good]]
        image = np.array([keypoints[m.queryIdx].pt for m in good], np.float64)
        poses, most = [], 0
        for threshold in self.config.reprojection_px:
            found, rvec, tvec, inliers = cv2.solvePnPRansac(
                world, image, self._K, None, reprojectionError=threshold, iterationsCount=500,
            )  # fmt: skip
            if not found or inliers is None or len(inliers) < self.config.min_inliers:
                continue
            poses.append(invert_pose(make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())))
            most = max(most, len(inliers))
            fitted = self._fitted(image[inliers.ravel()], world[inliers.ravel()], depth)
            poses += [] if fitted is None else [fitted]
        return Located(_distinct(poses), most, index) if poses else None

    def _fitted(self, pixels: np.ndarray, world: np.ndarray, depth: np.ndarray) -> np.ndarray | None:
        """The rigid fit of the frame's own depth at the matched ``pixels`` to their keyframe
        points ``world``, once more without the matches ``fit_m`` off it; None with too few, or
        where it moves the matches off their pixels (a median over the largest
        ``reprojection_px``: a depth that contradicts the image)."""
        camera = self._lifted(pixels, depth)
        near = np.isfinite(camera[:, 2])
        pose = None
        for _ in range(2):
            if near.sum() < self.config.min_inliers:
                break
            pose = rigid_fit(camera[near], world[near])
            near = np.linalg.norm(transform_points(pose, camera) - world, axis=1) <= self.config.fit_m
        if pose is None:
            return None
        seen = transform_points(invert_pose(pose), world)
        ahead = seen[:, 2] > 0
        off = np.linalg.norm(project_points(seen[ahead], self.intrinsics) - pixels[ahead], axis=1)
        return pose if ahead.all() and np.median(off) <= max(self.config.reprojection_px) else None

    def _lifted(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) of ``pixels`` (N, 2) at their depth; NaN where it has none."""
        height, width = depth.shape
        columns = np.clip(np.rint(pixels[:, 0]), 0, width - 1).astype(int)
        rows = np.clip(np.rint(pixels[:, 1]), 0, height - 1).astype(int)
        z = np.asarray(depth, np.float64)[rows, columns]
        points = np.full((len(pixels), 3), np.nan)
        held = z > 0
        points[held] = backproject(pixels[held, 0], pixels[held, 1], z[held], self.intrinsics)
        return points


def _distinct(poses: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """``poses`` without those within a centimetre and half a degree of one before them: RANSAC at
    neighbouring thresholds often keeps the same matches, and each pose costs the tracker a raycast."""
    kept: list[np.ndarray] = []
    for pose in poses:
        steps = [invert_pose(k) @ pose for k in kept]
        if all(np.linalg.norm(s[:3, 3]) > 0.01 or rotation_deg(s[:3, :3]) > 0.5 for s in steps):
            kept.append(pose)
    return tuple(kept)


def _moved(last: np.ndarray, pose: np.ndarray, config: FeatureConfig) -> bool:
    """Whether ``pose`` is at least ``keyframe_m`` or ``keyframe_deg`` from ``last``."""
    step = invert_pose(last) @ pose
    moved, turned = np.linalg.norm(step[:3, 3]), rotation_deg(step[:3, :3])
    return bool(moved >= config.keyframe_m or turned >= config.keyframe_deg)
