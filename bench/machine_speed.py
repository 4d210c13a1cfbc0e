"""Does this machine switch speeds? One network call after another for a while, then the calls'
times split into fast and slow, and the slow spells with their start and length.

Some shared machines run the same code at two speeds for seconds to minutes at a time
(docs/edge-speed.md "Closing numbers, part five"); a timing taken in a slow spell measures the
machine, not the code. Run this before timing, or beside a benchmark that failed, to see which
speed the machine is at and how long its spells last:

    .venv/bin/python -m bench.machine_speed MODEL FRAMES --seconds 180
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.edge_report import cpu_description, load_average
from bench.edge_speed import network_inputs

SLOW_FACTOR = 1.08  # a call this much slower than the fastest counts as slow
WINDOW = 5  # calls: a call is slow only where the calls around it are too, so one late call is no spell


@dataclass(frozen=True)
class Spell:
    """A run of consecutive slow calls: when it started (seconds from the first call) and how long."""

    start: float
    seconds: float
    calls: int


@dataclass(frozen=True)
class SpeedSummary:
    fast_median: float  # seconds a call, over the fast calls
    slow_median: float | None  # None: no slow call
    slow_share: float  # of all calls
    spells: list[Spell]


def speed_spells(
    starts: np.ndarray, seconds: np.ndarray, slow_factor: float = SLOW_FACTOR, window: int = WINDOW
) -> SpeedSummary:
    """The calls that started at ``starts`` and took ``seconds`` (same length, in order), split
    at ``slow_factor`` times the fastest call: a call is slow when it and the median of the
    ``window`` calls centred on it (fewer at the ends) are both above that, so the fastest call is
    always fast; consecutive slow calls form a spell."""
    starts, seconds = np.asarray(starts, float), np.asarray(seconds, float)
    if len(seconds) == 0 or len(starts) != len(seconds):
        raise ValueError(
            f"need as many call starts as call times, at least one: {len(starts)}, {len(seconds)}"
        )
    half = window // 2
    smooth = np.array([np.median(seconds[max(0, i - half) : i + half + 1]) for i in range(len(seconds))])
    slow = (smooth > slow_factor * seconds.min()) & (seconds > slow_factor * seconds.min())
    spells, first = [], None
    for i, is_slow in enumerate([*slow, False]):  # a fast sentinel closes a spell at the end
        if is_slow and first is None:
            first = i
        elif not is_slow and first is not None:
            end = starts[i - 1] + seconds[i - 1]
            spells.append(Spell(float(starts[first] - starts[0]), float(end - starts[first]), i - first))
            first = None
    return SpeedSummary(
        fast_median=float(np.median(seconds[~slow])),
        slow_median=float(np.median(seconds[slow])) if slow.any() else None,
        slow_share=float(slow.mean()),
        spells=spells,
    )


def time_calls(
    model: Path, frames: Path, seconds: float, *, threads: int, max_proposals: int
) -> tuple[np.ndarray, np.ndarray]:
    """The network of ``model`` on a3d-run's input for the first frame of ``frames``, called again
    and again for ``seconds`` (after one warm-up call): each call's start and duration."""
    from a3d.runtime.network.model import DetectorModel

    item = next(i for i in network_inputs(model, frames, max_proposals, count=1) if len(i.rois))
    detector = DetectorModel.load(model, threads=threads)
    feeds = (item.color_input, item.depth_input, item.rois, item.context_rois)
    detector.run(*feeds)
    starts, durations = [], []
    origin = time.perf_counter()
    while time.perf_counter() - origin < seconds:
        start = time.perf_counter()
        detector.run(*feeds)
        starts.append(start - origin)
        durations.append(time.perf_counter() - start)
    return np.array(starts), np.array(durations)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.machine_speed", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("model", type=Path, help="an a3d ONNX model")
    parser.add_argument("frames", type=Path, help="a frame folder; its first frame is fed")
    parser.add_argument("--seconds", type=float, default=180.0, help="how long to keep calling")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--max-proposals", type=int, default=500)
    args = parser.parse_args(argv)
    print(f"machine speed: {args.model.name}, {args.threads} threads, {args.seconds:.0f} s; "
          f"{cpu_description()}; {load_average()} at the start")  # fmt: skip
    starts, durations = time_calls(args.model, args.frames, args.seconds, threads=args.threads,
                                   max_proposals=args.max_proposals)  # fmt: skip
    summary = speed_spells(starts, durations)
    fast = f"it or the median of its {WINDOW} within {SLOW_FACTOR} x the fastest"
    print(f"  {len(durations)} calls; fastest {1e3 * durations.min():.1f} ms; "
          f"fast calls ({fast}) median {1e3 * summary.fast_median:.1f} ms")  # fmt: skip
    if summary.slow_median is None:
        print("  no slow call: one speed throughout")
        return 0
    ratio = summary.slow_median / summary.fast_median
    print(f"  slow calls median {1e3 * summary.slow_median:.1f} ms ({ratio:.2f} x), "
          f"{summary.slow_share:.0%} of the calls")  # fmt: skip
    for spell in summary.spells:
        print(f"  slow spell from {spell.start:6.1f} s for {spell.seconds:6.1f} s ({spell.calls} calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
