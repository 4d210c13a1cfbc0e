"""Camera poses from an RGB-D recording: frame-to-model tracking, as KinectFusion does.

Why: world boxes, labels drawn once and the object map need each frame's pose, and a RealSense
alone gives none. Each frame is aligned (OpenCV's RGB-D ``Odometry``: depth and photometric terms)
to the model fused so far, a hashed TSDF volume (OpenCV's ``Volume``), as it looks from the last
pose: the model's depth raycast there, beside the last frame's image, which was taken there. The
frame is then fused into the model at its new pose. Aligning to the model, which averages every
frame so far, rather than to the last frame keeps the drift small; the image's term holds the
camera where depth alone lets it slide (a wall and the floor fix no motion along both). The poses
are in the first frame's camera; ``gravity_alignment`` turns them into a3d's gravity-aligned
world (y down, a3d.runtime.mapping.world) from the gravity the frames show.

Limits: the scene is static; between two tracked frames the camera moves a few centimetres and
degrees (a hand-held camera at 5 to 10 frames a second; ``TrackerConfig`` bounds a step); a frame
further off (snapshots a metre apart, a dropped stretch) is placed by its image features where
they match a keyframe's (a3d.runtime.mapping.relocalise: textured rooms, as real ones are; plain
rendered walls give too few); nothing closes loops, so the drift grows with the path (measured:
docs/mapping.md "Poses from the depth").
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.gravity import rtilt_from_gravity
from a3d.runtime.mapping.relocalise import FeatureConfig, FeatureMap
from a3d.runtime.structures.geometry import Intrinsics, depth_seen_at
from a3d.runtime.structures.pose import transform_points


@dataclass(frozen=True)
class TrackerConfig:
    """``voxel_m``: the model's voxel (OpenCV's default, 3 m / 512; coarser ones drift further:
    bench.poses ``--voxel``); ``truncate_voxels``: its signed distance's truncation, in voxels (OpenCV's
    ratio); ``max_depth_m``: depth beyond
    this is neither fused nor tracked; ``max_step_m`` / ``max_turn_deg``: the largest move between
    two tracked frames that ICP may return; a frame is tracked when at least ``min_agreement`` of
    the model's pixels that it also sees lie within ``agree_m`` of its own depth after alignment;
    under ``sure_agreement`` the image features' pose is tried as well, and the one the depth
    agrees with more is kept (in a wide step the odometry can settle tens of centimetres off);
    ``refine_step_m`` / ``refine_turn_deg``: the largest correction ``refine`` may make;
    ``features``: the image features that place a frame the odometry lost, and
    ``settle_step_m`` / ``settle_turn_deg`` the largest correction the depth may then make to that
    place (PnP on a few dozen features can be tens of centimetres off); ``model_side``: the model,
    the odometry and the agreement work at this many pixels along the frame's longer side (None:
    the frame's size, as a smaller frame keeps its own), the image features at the frame's own (a
    pose does not depend on the image's size; half the size costs the model's raycast a quarter,
    and image features need the detail: docs/mapping.md "A source without poses")."""

    voxel_m: float = 3.0 / 512
    truncate_voxels: float = 7.0
    max_depth_m: float = 4.0
    max_step_m: float = 0.15
    max_turn_deg: float = 15.0
    agree_m: float = 0.05
    min_agreement: float = 0.5
    sure_agreement: float = 0.8
    refine_step_m: float = 0.05
    refine_turn_deg: float = 3.0
    features: FeatureConfig = field(default_factory=FeatureConfig)
    settle_step_m: float = 0.3
    settle_turn_deg: float = 30.0
    model_side: int | None = None


@dataclass(frozen=True)
class Tracked:
    """One frame's outcome: ``pose`` (4, 4) camera-to-first-camera, None when it was not tracked
    (``note`` says why); ``agreement`` the share of the model's pixels that its depth confirms;
    ``relocalised``: the odometry lost it and image features found it (a3d.runtime.mapping.relocalise)."""

    pose: np.ndarray | None
    agreement: float
    note: str = ""
    relocalised: bool = False


def check_opencv() -> None:
    """InputError unless this OpenCV has the 3D module's Odometry and Volume (OpenCV 5)."""
    if not (hasattr(cv2, "Odometry") and hasattr(cv2, "Volume")):
        raise InputError(
            f"pose tracking needs OpenCV 5 (its Odometry and Volume); this is OpenCV {cv2.__version__}: "
            "pip install 'opencv-python-headless>=5'"
        )


class DepthTracker:
    """Tracks the frames of one camera (one size and intrinsics), in order (module docstring)."""

    def __init__(
        self, intrinsics: Intrinsics, size: tuple[int, int], config: TrackerConfig = TrackerConfig()
    ):
        check_opencv()
        self.intrinsics, self.size, self.config = intrinsics, size, config
        longer = max(size)
        scale = config.model_side / longer if config.model_side and longer > config.model_side else 1.0
        height, width = (max(1, round(side * scale)) for side in size)
        self._model_size = (height, width)
        self._model_K = intrinsics.resized(width / size[1], height / size[0])  # the model's camera
        K = self._model_K.matrix().astype(np.float32)
        volume = cv2.VolumeSettings(cv2.VolumeType_HashTSDF)
        volume.setCameraIntegrateIntrinsics(K)
        volume.setCameraRaycastIntrinsics(K)
        volume.setIntegrateWidth(width)
        volume.setIntegrateHeight(height)
        volume.setRaycastWidth(width)
        volume.setRaycastHeight(height)
        volume.setDepthFactor(1.0)  # metres in, as a3d's frames hold them
        volume.setVoxelSize(config.voxel_m)
        volume.setTsdfTruncateDistance(config.truncate_voxels * config.voxel_m)
        volume.setMaxDepth(config.max_depth_m)
        self._volume = cv2.Volume(cv2.VolumeType_HashTSDF, volume)
        tracking = _odometry_settings(K, config.max_depth_m, config.max_step_m, config.max_turn_deg)
        self._odometry = cv2.Odometry(cv2.OdometryType_RGB_DEPTH, tracking, cv2.OdometryAlgoType_COMMON)
        refining = _odometry_settings(K, config.max_depth_m, config.refine_step_m, config.refine_turn_deg)
        self._refining = cv2.Odometry(cv2.OdometryType_DEPTH, refining, cv2.OdometryAlgoType_COMMON)
        settling = _odometry_settings(K, config.max_depth_m, config.settle_step_m, config.settle_turn_deg)
        self._settling = cv2.Odometry(cv2.OdometryType_DEPTH, settling, cv2.OdometryAlgoType_COMMON)
        self._features = FeatureMap(intrinsics, config.features)
        self._pose: np.ndarray | None = None  # the last tracked frame's
        self._gray: np.ndarray | None = None  # the last tracked frame's image at the model's size

    def track(self, depth: np.ndarray, color: np.ndarray) -> Tracked:
        """Align ``depth`` ((H, W) metres, 0 = missing) to the model and fuse it there; the first
        frame defines the model's frame. Where the odometry loses the frame, or leaves fewer than
        ``sure_agreement`` of the model agreeing, image features are asked too (``relocalise``)
        and the pose the depth agrees with more is taken; the note says so."""
        depth = np.ascontiguousarray(depth, np.float32)
        gray = cv2.cvtColor(color, cv2.COLOR_BGR2GRAY)
        if depth.shape != self.size:
            raise InputError(
                f"depth is {depth.shape[0]}x{depth.shape[1]}, the recording's {self.size[0]}x{self.size[1]}"
            )
        if self._pose is None:
            if not (depth > 0).any():
                return Tracked(None, 0.0, "no depth to start the model from")
            return self._fuse(np.eye(4), depth, gray, Tracked(np.eye(4), 1.0))
        small, small_gray = self._shrunk(depth), self._shrunk(gray)
        points, model_depth = self._model(self._pose)
        Rt = _align(
            self._odometry, cv2.OdometryFrame(model_depth, self._gray), cv2.OdometryFrame(small, small_gray)
        )
        tracked = Tracked(None, 0.0, "the odometry found no alignment to the model")
        if Rt is not None:
            agreement = self.agreement(points, Rt, small)
            if agreement >= self.config.sure_agreement:
                pose = self._pose @ np.linalg.inv(Rt)
                return self._fuse(pose, depth, gray, Tracked(pose, agreement))
            if agreement >= self.config.min_agreement:
                tracked = Tracked(self._pose @ np.linalg.inv(Rt), agreement)
            else:
                tracked = Tracked(None, agreement, f"only {agreement:.0%} of the model agrees with its depth")
        found = self.relocalise(depth, gray)
        if found.pose is not None and found.agreement > tracked.agreement:
            if tracked.pose is None:
                lost = f"the odometry lost it ({tracked.note})"
            else:
                lost = f"the odometry's alignment left only {tracked.agreement:.0%} of the model agreeing"
            return self._fuse(found.pose, depth, gray, replace(found, note=f"{lost}; {found.note}"))
        if tracked.pose is not None:
            return self._fuse(tracked.pose, depth, gray, tracked)
        return replace(tracked, note=f"{tracked.note}; {found.note}")

    def relocalise(self, depth: np.ndarray, gray: np.ndarray) -> Tracked:
        """The frame's pose from image features matched to a keyframe's: of the poses
        ``FeatureMap.locate`` gives, each as it is and aligned on the depth from there, the one
        the depth agrees with most (depth alone can slide along a wall or the floor; features
        on depth edges sit centimetres off), kept where it agrees as much as a tracked frame's
        must; not fused."""
        located = self._features.locate(gray, depth)
        if located is None:
            return Tracked(None, 0.0, "no keyframe's image features place it either")
        small = self._shrunk(depth)
        best, share, settled = located.poses[0], -1.0, False
        for pose in located.poses:
            points, model_depth = self._model(pose)
            Rt = _align(self._settling, cv2.OdometryFrame(model_depth), cv2.OdometryFrame(small))
            for move in [np.eye(4)] + ([] if Rt is None else [Rt]):
                agreement = self.agreement(points, move, small)
                if agreement > share:
                    best, share, settled = pose @ np.linalg.inv(move), agreement, move is Rt
        if share < self.config.min_agreement:
            note = f"placed by its image features, only {share:.0%} of the model agrees there"
            return Tracked(None, share, note)
        note = f"placed by {located.inliers} image features matched to a keyframe's"
        return Tracked(best, share, note + settled * ", then on the depth", relocalised=True)

    def _fuse(self, pose: np.ndarray, depth: np.ndarray, gray: np.ndarray, tracked: Tracked) -> Tracked:
        """Take ``pose`` as the frame's: fuse its depth into the model, keep its features where it
        is a keyframe; ``tracked``, with a copy of the pose."""
        self._pose, self._gray = pose, self._shrunk(gray)
        self._volume.integrate(self._shrunk(depth), pose.astype(np.float32))  # track() made it float32
        self._features.add(gray, depth, pose)
        return replace(tracked, pose=pose.copy())

    def refine(self, depth: np.ndarray, pose: np.ndarray) -> np.ndarray | None:
        """``pose`` (a tracked frame's) aligned again, by depth ICP, to the model as it stands once
        every frame is fused: each frame was tracked against the model of the frames before it,
        and re-aligning every frame to the one model of all of them takes out most of their
        frame-to-frame disagreement (docs/mapping.md "Poses from the depth"). None when ICP
        finds no correction within ``refine_step_m`` and ``refine_turn_deg``."""
        _, model_depth = self._model(pose)
        frame = cv2.OdometryFrame(self._shrunk(np.ascontiguousarray(depth, np.float32)))
        Rt = _align(self._refining, cv2.OdometryFrame(model_depth), frame)
        return None if Rt is None else np.asarray(pose, np.float64) @ np.linalg.inv(Rt)

    def _shrunk(self, image: np.ndarray) -> np.ndarray:
        """``image`` (the frame's size) at the model's (nearest neighbour: no depth invented at edges)."""
        if image.shape[:2] == self._model_size:
            return image
        height, width = self._model_size
        return cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST)

    def _model(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The model raycast from ``pose``: its points (H, W, 3) in that camera, NaN where it holds
        nothing, and their depth (H, W) float32, 0 there."""
        points = np.asarray(self._volume.raycast(np.asarray(pose, np.float32))[0])[..., :3]
        return points, np.where(np.isfinite(points[..., 2]), points[..., 2], 0).astype(np.float32)

    def agreement(self, points: np.ndarray, Rt: np.ndarray, depth: np.ndarray) -> float:
        """The share of the model's points (the last pose's camera) that, moved by ``Rt`` into
        the frame's camera, land on a pixel of ``depth`` (the model's size) whose depth is within
        ``agree_m`` of theirs, over those that land on a pixel with depth (0 when none does)."""
        moved = transform_points(Rt, points[np.isfinite(points[..., 2])].astype(np.float64))
        seen = depth_seen_at(moved, depth, self._model_K)
        both = seen > 0
        if not both.any():
            return 0.0
        return float(np.mean(np.abs(seen[both] - moved[both, 2]) <= self.config.agree_m))


def _align(odometry: cv2.Odometry, source: cv2.OdometryFrame, target: cv2.OdometryFrame) -> np.ndarray | None:
    """The rigid transform (4, 4) taking ``source``'s camera to ``target``'s (both prepared here for
    ``odometry``), None when it finds none within its settings' bounds."""
    odometry.prepareFrame(source)
    odometry.prepareFrame(target)
    found, Rt = odometry.compute(source, target)
    return np.asarray(Rt, np.float64) if found else None


def _odometry_settings(
    K: np.ndarray, max_depth_m: float, step_m: float, turn_deg: float
) -> cv2.OdometrySettings:
    """OpenCV's odometry settings for the camera ``K``: depth used up to ``max_depth_m``, a move of at
    most ``step_m`` and ``turn_deg`` accepted."""
    settings = cv2.OdometrySettings()
    settings.setCameraMatrix(K)
    settings.setMaxDepth(max_depth_m)
    settings.setMaxTranslation(step_m)
    settings.setMaxRotation(turn_deg)
    return settings


@dataclass(frozen=True)
class GravityAlignment:
    """The rotation that turns the tracking frame into a3d's world (its gravity on +y), the
    frames it was taken from and the median angle between their gravity and the mean."""

    rotation: np.ndarray
    frames: int
    spread_deg: float


def gravity_alignment(poses: list[np.ndarray], downs: list[np.ndarray]) -> GravityAlignment:
    """The mean of the frames' gravity (``downs``: each a unit down vector in its camera, from its
    R_tilt) taken into the tracking frame by their ``poses``, turned onto a3d's down, +y. The
    heading is the first camera's. ValueError when no frame gave gravity."""
    if not downs:
        raise ValueError("no frame's gravity to align the poses with")
    world = np.array([pose[:3, :3] @ down for pose, down in zip(poses, downs, strict=True)])
    world /= np.linalg.norm(world, axis=1, keepdims=True)
    mean = world.mean(axis=0)
    mean /= np.linalg.norm(mean)
    spread = np.degrees(np.arccos(np.clip(world @ mean, -1.0, 1.0)))
    return GravityAlignment(rtilt_from_gravity(mean), len(downs), float(np.median(spread)))
