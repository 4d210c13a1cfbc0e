"""a3d-run's end-of-run summary: what was found, what degraded, where the outputs went.

Each frame's line holds ~200 detections with scores down to the written threshold; the summary
counts, per class, only those at or above the viewer's threshold (``--view-min-score``: with
calibrated scores a detection there is as likely right as wrong), so that a user sees what was
found, and says which scores they are: the model's calibrated ones (the chance a detection is
right, a3d.runtime.postprocess.score_calibration) or the network's softmax. It also
counts the frames whose gravity was a fallback (by method) and the frames whose line carries
notes, and gives the run's rate. The lines start with ``a3d-run: summary:``; the run's last
line stays "N frames written to OUTPUT, M failed".
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import CLASSES


@dataclass
class RunSummary:
    """Accumulates the processed frames of a run (``add``) and the failed ones (``fail``)."""

    min_score: float
    calibrated: bool = False  # the scores are the model's calibrated ones
    started: float = field(default_factory=time.monotonic)
    frames: int = 0
    failed: int = 0
    per_class: Counter[str] = field(default_factory=Counter)
    gravity: Counter[str] = field(default_factory=Counter)
    noted: Counter[str] = field(default_factory=Counter)
    dropped: int | None = None  # stale frames a live source dropped (None: not a live run)

    def add(self, det: FrameDetections) -> None:
        self.frames += 1
        shown = np.asarray(det.class_ids)[np.asarray(det.scores) >= self.min_score]
        self.per_class.update(CLASSES[c] for c in shown.tolist())
        self.gravity[(det.gravity or "unknown").split(" (")[0]] += 1
        self.noted.update({_note_kind(note) for note in det.notes})

    def fail(self) -> None:
        self.failed += 1

    def lines(self, outputs: list[str], now: float | None = None) -> list[str]:
        """The summary lines (without the program prefix); ``outputs`` like "detections -> FILE"."""
        elapsed = (time.monotonic() if now is None else now) - self.started
        done = self.frames + self.failed
        rate = done / elapsed if elapsed > 0 else 0.0
        found = ", ".join(f"{name} {n}" for name, n in self.per_class.most_common()) or "none"
        fallbacks = sum(n for source, n in self.gravity.items() if source.startswith("fallback"))
        sources = ", ".join(f"{source} {n}" for source, n in sorted(self.gravity.items())) or "no frame"
        notes = ", ".join(f"'{kind}' {n}" for kind, n in sorted(self.noted.items())) or "none"
        dropped = "" if self.dropped is None else f", {self.dropped} stale frames dropped"
        scores = "calibrated scores: the chance a detection is right" if self.calibrated else "softmax scores"
        return [
            f"{done} frames ({self.failed} failed{dropped}) in {elapsed:.1f} s, {rate:.2f} frames/s",
            f"detections scoring >= {self.min_score:g} (the viewer's threshold; {scores}): {found}",
            f"gravity fallbacks on {fallbacks} frames (sources: {sources}); frames with notes: {notes}",
            f"outputs: {'; '.join(outputs)}",
        ]


def _note_kind(note: str) -> str:
    """A note without its numbers, to count frames per kind: "proposals capped at 2000" ->
    "proposals capped at N"."""
    return " ".join("N" if word.rstrip("%:,").replace(".", "").isdigit() else word for word in note.split())
