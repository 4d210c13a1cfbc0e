"""One RGB-D frame in memory, whatever it came from, and a frame's annotated objects.

Every frame source (the a3d frame folder, data sets, bags, cameras) yields ``Frame``; the
pipeline takes nothing else. Inside a3d colour is uint8 BGR, OpenCV's order, because every stage
that touches it (superpixels, network input, image files) is OpenCV; the Python API
(``a3d.runtime.Detector``) takes RGB, as other detection libraries do, and converts once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from a3d.runtime.structures.boxes import boxes_array
from a3d.runtime.structures.classes import class_index
from a3d.runtime.structures.geometry import Intrinsics

if TYPE_CHECKING:
    from a3d.runtime.sources.proposals_file import PrecomputedProposals


@dataclass(frozen=True)
class GroundTruth:
    """A frame's annotated objects, as arrays of N rows.

    ``boxes3d`` (N, 7) in the camera frame with theta in the frame's R_tilt tilt frame;
    ``boxes2d_visible`` (N, 4) the box of the visible pixels (the paper's gt2d_sel);
    ``boxes2d_amodal`` (N, 4) the projected whole 3D box, clipped to the image; ``instance_ids``
    (N,) the object's value in ``NAME.instances.png`` (0 = not in the map).
    """

    classes: list[str]
    class_ids: np.ndarray  # (N,) int64, 0-based CLASSES index
    boxes3d: np.ndarray  # (N, 7) float64
    boxes2d_visible: np.ndarray  # (N, 4) float64
    boxes2d_amodal: np.ndarray  # (N, 4) float64
    instance_ids: np.ndarray  # (N,) int64

    def __len__(self) -> int:
        return len(self.classes)

    @classmethod
    def from_classes(
        cls,
        classes: Sequence[str],
        boxes3d: Any,
        boxes2d_visible: Any,
        boxes2d_amodal: Any,
        instance_ids: Any = None,
    ) -> GroundTruth:
        """Build from class names (ValueError if unknown) and array-likes; N = 0 is fine."""
        n = len(classes)
        return cls(
            classes=list(classes),
            class_ids=np.array([class_index(name) for name in classes], dtype=np.int64),
            boxes3d=boxes_array(boxes3d, n),
            boxes2d_visible=np.asarray(boxes2d_visible, dtype=np.float64).reshape(n, 4),
            boxes2d_amodal=np.asarray(boxes2d_amodal, dtype=np.float64).reshape(n, 4),
            instance_ids=(
                np.zeros(n, np.int64)
                if instance_ids is None
                else np.asarray(instance_ids, np.int64).reshape(n)
            ),
        )


@dataclass(frozen=True, eq=False)
class Frame:
    """A validated frame: colour uint8 BGR (H, W, 3), depth float32 metres (H, W), 0 = missing.

    ``R_tilt`` (3, 3) ``p_tilt = R_tilt p_cam``, or None: estimate it from the depth.
    ``origin`` names the frame in messages ("PATH", "bag.bag@12.5 s", "realsense:SERIAL#3");
    ``color_file`` / ``depth_file`` are the files a detections line names (None for arrays).
    ``proposals``: precomputed segment proposals to use instead of computing them; ``truth``:
    ground truth when the source has it; ``timestamp`` in seconds when the source has one.
    ``pose`` (4, 4) camera-to-world (``p_world = pose[:3, :3] p_cam + pose[:3, 3]``, metres;
    a3d.runtime.structures.pose) when the source has one; ``pose_note`` says why a frame of a posed
    source has none (a bad or missing pose file, a time outside the trajectory), for its line's notes.
    """

    name: str
    color: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    R_tilt: np.ndarray | None = None
    origin: str = ""
    color_file: str | None = None
    depth_file: str | None = None
    proposals: PrecomputedProposals | None = None
    truth: GroundTruth | None = None
    timestamp: float | None = None
    warnings: tuple[str, ...] = ()  # readable but suspicious, e.g. "depth has no valid pixels"
    pose: np.ndarray | None = None
    pose_note: str = ""

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width)."""
        return self.depth.shape[0], self.depth.shape[1]
