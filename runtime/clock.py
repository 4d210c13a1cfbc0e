"""A lap timer shared by the pipeline's stages and the proposal front end's own stages, so a
benchmark reads both breakdowns the same way (bench.frontend, bench.live_rate)."""

from __future__ import annotations

import time


class Clock:
    """``lap(stage)`` adds the wall seconds since the previous lap to ``timing[stage]``; with
    ``timing=None`` it times nothing (the cost of an untimed call is one comparison)."""

    def __init__(self, timing: dict[str, float] | None) -> None:
        self.timing = timing
        self.last = time.perf_counter() if timing is not None else 0.0

    def lap(self, stage: str) -> None:
        if self.timing is None:
            return
        now = time.perf_counter()
        self.timing[stage] = self.timing.get(stage, 0.0) + (now - self.last)
        self.last = now
