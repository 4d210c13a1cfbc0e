"""Camera poses for a source that has none, tracked from its depth as its frames are read.

Why: the object map (a3d.runtime.mapping.object_map) needs each frame's pose, and a RealSense
alone gives none. a3d-poses tracks a whole recording first, refines every pose against the model
of all its frames and levels the world by their mean gravity; a live run cannot wait for the end.
Here each frame is tracked as it is read, by the same tracker (a3d.runtime.mapping.odometry: depth
odometry to the model fused so far, image features where the odometry loses the frame), at the
working size (a3d.runtime.frontend.working_size; its model at ``MODEL_SIDE`` across), and
carries its pose in the first tracked camera's frame; the map levels that world by the first
mapped frame's gravity. A frame the tracker loses carries no pose and a note that says why (the
map counts it skipped); one that image features placed says so in its note, as a3d-poses does.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Iterator
from dataclasses import replace

from a3d.runtime.frontend.working_size import working_frame
from a3d.runtime.mapping.odometry import DepthTracker, TrackerConfig, check_opencv
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.structures.frame import Frame

MODEL_SIDE = 320
"""The tracker's model and odometry at 320 pixels across (``TrackerConfig.model_side``: half a
640-wide frame), its image features at the frame's own size: a run that tracks as it goes pays
for every frame, and this halves that for the same path and map (docs/mapping.md "A source
without poses"; with the features at 320 across too, a real snapshot was lost)."""


class FramePoses:
    """Tracks the frames of one camera, in the order they are read (module docstring)."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        check_opencv()
        self.config = config or TrackerConfig(model_side=MODEL_SIDE)
        self.tracker: DepthTracker | None = None
        self._lock = threading.Lock()  # a run may read the next frame on a thread of its own

    def track(self, frame: Frame) -> Frame:
        """``frame`` with its tracked ``pose`` (camera to the first tracked camera), or with none
        and a ``pose_note`` saying why."""
        work = working_frame(frame).frame
        with self._lock:
            if self.tracker is None:
                self.tracker = DepthTracker(work.intrinsics, work.depth.shape, self.config)
            elif (work.intrinsics, work.depth.shape) != (self.tracker.intrinsics, self.tracker.size):
                return replace(
                    frame, pose=None, pose_note="not tracked: another camera than the first frame's"
                )
            tracked = self.tracker.track(work.depth, work.color)
        if tracked.pose is None:
            return replace(frame, pose=None, pose_note=f"not tracked: {tracked.note}")
        return replace(frame, pose=tracked.pose, pose_note=tracked.note if tracked.relocalised else "")


def with_tracked_poses(loaders: Iterable[FrameLoader], poses: FramePoses) -> Iterator[FrameLoader]:
    """The ``loaders``, each reading its frame with the pose ``poses`` tracks for it; closing this
    closes the loaders' iterator (a camera stops however the run ends)."""
    frames = iter(loaders)
    try:
        for loader in frames:
            yield replace(loader, load=lambda loader=loader: poses.track(loader.load()))
    finally:
        close = getattr(frames, "close", None)
        if close is not None:
            close()
