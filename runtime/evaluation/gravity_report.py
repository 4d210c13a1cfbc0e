"""How far each detections line's gravity is from the ground truth's: the error mAP cannot see.

The metric re-expresses a line's boxes in the ground truth's tilt frame before matching, so a
wrong gravity estimate barely moves the mAP, while every box a user sees is tilted by it. This
report gives, over the frames that have both a line and ground truth, the angle between the
two gravity directions (row 1 of each R_tilt, the tilt frame's down axis in the camera frame)
as median, 95th percentile and max in degrees, and how many lines came from each gravity
source ("given", "estimated", "fallback: <method>"; "unknown" for lines written before the
field existed).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from a3d.runtime.evaluation.metric import FrameTruth
from a3d.runtime.io.detections_io import FrameDetections


@dataclass(frozen=True)
class GravityReport:
    """Per-frame angles (degrees, in frame-name order) and the count of lines per gravity source."""

    frames: list[str]
    angles_deg: np.ndarray
    sources: dict[str, int]

    def summary(self) -> dict:
        """The numbers for eval.json (None where there is no frame)."""
        a = self.angles_deg
        stats = (np.median(a), np.percentile(a, 95), a.max()) if len(a) else (None, None, None)
        median, p95, worst = (None if v is None else float(v) for v in stats)
        return {
            "frames": len(a),
            "median_deg": median,
            "p95_deg": p95,
            "max_deg": worst,
            "sources": self.sources,
        }

    def format(self) -> str:
        """One line for the evaluation printout."""
        s = self.summary()
        if not s["frames"]:
            return "gravity vs ground truth: no frame with both a line and ground truth"
        sources = ", ".join(f"{name} {n}" for name, n in sorted(self.sources.items()))
        return (
            f"gravity vs ground truth ({s['frames']} frames; not seen by the mAP): "
            f"angle median {s['median_deg']:.2f}, p95 {s['p95_deg']:.2f}, max {s['max_deg']:.2f} degrees; "
            f"sources: {sources}"
        )


def gravity_report(
    truth: Mapping[str, FrameTruth], detections: Mapping[str, FrameDetections]
) -> GravityReport:
    """The angle between each line's gravity and its frame's ground-truth gravity."""
    frames = sorted(name for name in detections if name in truth)
    down = np.array([detections[name].R_tilt[1] for name in frames]).reshape(-1, 3)
    true_down = np.array([truth[name].R_tilt[1] for name in frames]).reshape(-1, 3)
    cosine = np.sum(down * true_down, axis=1) / (
        np.linalg.norm(down, axis=1) * np.linalg.norm(true_down, axis=1)
    )
    angles = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
    sources = Counter(_source_kind(detections[name].gravity) for name in frames)
    return GravityReport(frames, angles, dict(sources))


def _source_kind(source: str | None) -> str:
    """ "fallback: filled depth (why...)" -> "fallback: filled depth"; None -> "unknown"."""
    return "unknown" if source is None else source.split(" (")[0]
