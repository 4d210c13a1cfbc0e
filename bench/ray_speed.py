"""Ray's cost per frame: a3d-run --ray on a local Ray against plain a3d-run, on the same frames.

Runs, in this order and in this process: plain a3d-run (``--threads`` threads, default 2, with
``--overlap off``: one frame at a time, as each Ray worker runs them), then a local Ray of
``--workers x --worker-threads`` CPUs (default 2 x 1, started and timed on its own: a cluster
starts once, not per run) and ``ray_detect`` (what ``a3d-run SOURCE --ray`` runs) on it.
For each it prints the wall time, frames/s, the pipeline's own seconds per frame (the lines'
``timing.total``) and the overhead per frame: the CPU-slot seconds not spent in the pipeline,
(slots x wall - sum of the frames' pipeline time) / frames, where the slots are the run's
workers (1 for a3d-run). That is what Ray adds (actors and their model loads, scheduling,
moving blocks, part files, the merge, a tail of idle workers) beside what a3d-run's own loop costs.
Last, whether the two files hold the same lines (timing aside), the CPU and the load average.

    .venv/bin/a3d-synth /tmp/rayb --frames 20 --seed 5 --split test=1
    .venv/bin/python -m bench.ray_speed /tmp/rayb/test --model samples/model.onnx [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

from a3d.runtime.cli import run as run_cli
from a3d.runtime.scale import ray_detect
from bench.edge_report import cpu_description, load_average


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _report(label: str, wall: float, lines: list[dict], slots: int) -> None:
    """One run's line: wall, frames/s, pipeline seconds per frame and the overhead per frame."""
    n = len(lines)
    pipeline = sum(line["timing"]["total"] for line in lines)
    overhead = (slots * wall - pipeline) / n
    print(
        f"{label:34s} wall {wall:6.1f} s  {n / wall:5.2f} frames/s  pipeline {pipeline / n:.3f} s/frame  "
        f"overhead {overhead:.3f} s/frame (x {slots} slot{'s' if slots > 1 else ''})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("frames", type=Path, help="a frame folder (or another source every worker can read)")
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--threads", type=int, default=2, help="plain a3d-run's threads")
    parser.add_argument("--workers", type=int, default=2, help="Ray workers")
    parser.add_argument("--worker-threads", type=int, default=1, help="each Ray worker's threads")
    args = parser.parse_args()
    import ray

    work = Path(tempfile.mkdtemp(prefix="a3d_ray_speed_"))
    plain, spread = work / "plain.jsonl", work / "ray.jsonl"
    start = time.perf_counter()
    common = ["--model", str(args.model), "--headless", "--overlap", "off"]
    code = run_cli.main([str(args.frames), *common, "--threads", str(args.threads), "--output", str(plain)])
    plain_wall = time.perf_counter() - start
    start = time.perf_counter()
    cpus = args.workers * args.worker_threads
    ray.init(num_cpus=cpus, include_dashboard=False, logging_level=logging.ERROR)
    ray_start = time.perf_counter() - start
    start = time.perf_counter()
    result = ray_detect(args.frames, args.model, spread, workers=args.workers, threads=args.worker_threads)
    ray_wall = time.perf_counter() - start
    ray.shutdown()

    plain_lines, ray_lines = _lines(plain), _lines(spread)
    print(f"\n{len(plain_lines)} frames of {args.frames}, model {args.model} (a3d-run exit {code}, "
          f"Ray: {result.written} written, {len(result.failed)} failed)")  # fmt: skip
    _report(f"a3d-run, {args.threads} threads", plain_wall, plain_lines, 1)
    _report(f"Ray, {args.workers} x {args.worker_threads} thread(s)", ray_wall, ray_lines, args.workers)
    print(f"{'Ray start (once per cluster)':34s} {ray_start:.1f} s")
    per_frame = (ray_wall - plain_wall) / max(1, len(ray_lines))
    print(
        f"Ray against a3d-run: {plain_wall / ray_wall:.2f}x the frames/s, {per_frame:+.3f} s wall per frame"
    )
    same = [{k: v for k, v in line.items() if k != "timing"} for line in plain_lines] == [
        {k: v for k, v in line.items() if k != "timing"} for line in ray_lines
    ]
    print(f"same lines (timing aside): {'yes' if same else 'NO'}")
    print(f"{cpu_description()}; {load_average()}")
    print(f"outputs in {work}")


if __name__ == "__main__":
    main()
