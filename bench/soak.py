"""Soak: a3d-run over thousands of frames; its resident memory must not keep growing.

    .venv/bin/python -m bench.soak MODEL [--frames 2000] [--distinct 8] [--size 427x561]
        [--work /tmp/a3d_soak] [--interval 2] [--warmup 100] [--threads 2] [--overlap]
        [--max-proposals N] [--save]

A long run is where leaks show: per-frame buffers kept alive, caches without a bound, ONNX
Runtime arenas that keep growing with the RoI count, rerun's recording. This writes
``--distinct`` synthetic frames once with a3d-synth (kept in WORK/synth_SIZE_K, reused) and links
them under ``--frames`` names (symlinks, WORK/frames), runs ``a3d-run`` on them as its own
process (``--headless``; ``--save`` writes WORK/soak.rrd instead, to include rerun's logging),
and samples that process's resident memory (psutil) every ``--interval`` seconds together with
the frames it has written (the lines of its output).

It prints a sample every ~10 % of the run, then the RSS after warm-up (the first sample with at
least ``--warmup`` frames written: the allocator, ONNX Runtime's arena and OpenCV's buffers
have reached their working size), the peak after it and the RSS at the last sample, the growth
end / warm-up in %, and the least-squares slope after warm-up in MiB per 1000 frames. Target:
growth < 5 % (exit status 0; 1 above it; 2 if a3d-run itself failed).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import psutil

TARGET_GROWTH = 0.05
MIB = 2**20
FRAME_FILES = ("color.png", "depth.png", "meta.json")  # what a3d-run reads (no gt: --headless)


@dataclass(frozen=True)
class Sample:
    seconds: float
    frames: int  # lines written so far
    rss: int  # bytes


def _arguments() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path, help="model.onnx for a3d-run")
    p.add_argument("--frames", type=int, default=2000, help="frames in the run (default %(default)s)")
    p.add_argument("--distinct", type=int, default=8, help="distinct synthetic frames (default %(default)s)")
    p.add_argument("--size", default="427x561", help="synthetic image size HxW (default %(default)s)")
    p.add_argument("--seed", type=int, default=5, help="a3d-synth seed (default %(default)s)")
    p.add_argument("--work", type=Path, default=Path("/tmp/a3d_soak"), help="work folder (%(default)s)")
    p.add_argument(
        "--interval", type=float, default=2.0, help="seconds between samples (default %(default)s)"
    )
    p.add_argument("--warmup", type=int, default=100, help="frames before the reference sample (%(default)s)")
    p.add_argument("--threads", type=int, default=2, help="a3d-run --threads (default %(default)s)")
    p.add_argument("--overlap", action="store_true", help="a3d-run --overlap on (default: a3d-run's auto)")
    p.add_argument("--max-proposals", type=int, help="a3d-run --max-proposals (default: the model's)")
    p.add_argument("--save", action="store_true", help="log to WORK/soak.rrd instead of --headless")
    args = p.parse_args()
    if args.frames <= args.warmup:
        p.error("--frames must be larger than --warmup")
    return args


def synthetic_frames(args: argparse.Namespace) -> Path:
    """WORK/synth_SIZE_K/train: ``--distinct`` frames from a3d-synth (written once, then reused)."""
    out = args.work / f"synth_{args.size}_{args.distinct}_{args.seed}"
    folder = out / "train"
    if len(list(folder.glob("*.color.png"))) != args.distinct:
        shutil.rmtree(out, ignore_errors=True)
        synth = Path(sys.executable).with_name("a3d-synth")
        command = [str(synth), str(out), "--frames", str(args.distinct), "--seed", str(args.seed)]
        subprocess.run([*command, "--split", "test=0", "--size", args.size], check=True, capture_output=True)
    return folder


def linked_folder(source: Path, count: int, work: Path) -> Path:
    """WORK/frames: ``count`` frames f000000... each a set of symlinks to one of the source frames."""
    names = sorted(p.name.removesuffix(".color.png") for p in source.glob("*.color.png"))
    folder = work / "frames"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    shutil.copy(source / "intrinsics.json", folder / "intrinsics.json")
    for i in range(count):
        name = names[i % len(names)]
        for suffix in FRAME_FILES:
            if (source / f"{name}.{suffix}").exists():
                (folder / f"f{i:06d}.{suffix}").symlink_to(source / f"{name}.{suffix}")
    return folder


class LineCounter:
    """Lines of a growing file, counted incrementally."""

    def __init__(self, path: Path) -> None:
        self.path, self.offset, self.lines = path, 0, 0

    def count(self) -> int:
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            return 0
        self.offset += len(data)
        self.lines += data.count(b"\n")
        return self.lines


def soak(args: argparse.Namespace, folder: Path) -> tuple[list[Sample], int]:
    """Run a3d-run on ``folder`` and sample it until it exits: (samples, exit status)."""
    output = args.work / "detections.jsonl"
    output.unlink(missing_ok=True)
    command = [sys.executable, "-m", "a3d.runtime.cli.run", str(folder), "--model", str(args.model)]
    command += ["--output", str(output), "--threads", str(args.threads)]
    command += ["--save", str(args.work / "soak.rrd")] if args.save else ["--headless"]
    command += ["--overlap", "on"] if args.overlap else []
    command += ["--max-proposals", str(args.max_proposals)] if args.max_proposals else []
    print(" ".join(command), flush=True)
    counter, samples = LineCounter(output), []
    with open(args.work / "a3d-run.stderr", "w") as stderr:
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr)
        watched = psutil.Process(process.pid)
        start = time.monotonic()
        report_every = max(args.frames // 10, 1)
        next_report = 0
        while process.poll() is None:
            try:
                rss = watched.memory_info().rss
            except psutil.NoSuchProcess:
                break
            sample = Sample(time.monotonic() - start, counter.count(), rss)
            samples.append(sample)
            if sample.frames >= next_report:
                print(
                    f"  {sample.seconds:7.0f} s  {sample.frames:6d} frames  RSS {sample.rss / MIB:8.1f} MiB",
                    flush=True,
                )
                next_report = (sample.frames // report_every + 1) * report_every
            time.sleep(args.interval)
        status = process.wait()
    counter.count()
    print(f"a3d-run exit status {status}, {counter.lines} frames written ({args.work / 'a3d-run.stderr'})")
    return samples, status


def summary(samples: list[Sample], warmup: int) -> float:
    """Print the memory summary; returns the growth end / warm-up (a fraction)."""
    after = [s for s in samples if s.frames >= warmup]
    if len(after) < 2:
        raise SystemExit(
            f"too few samples after {warmup} frames ({len(after)}): lower --interval or --warmup"
        )
    first, last = after[0], after[-1]
    peak = max(s.rss for s in after)
    growth = (last.rss - first.rss) / first.rss
    frames = np.array([s.frames for s in after], float)
    slope = np.polyfit(frames, np.array([s.rss for s in after], float), 1)[0] if np.ptp(frames) else 0.0
    rate = (last.frames - first.frames) / max(last.seconds - first.seconds, 1e-9)
    print(f"RSS after warm-up ({first.frames} frames, {first.seconds:.0f} s): {first.rss / MIB:.1f} MiB")
    print(f"RSS at the end     ({last.frames} frames, {last.seconds:.0f} s): {last.rss / MIB:.1f} MiB")
    print(f"peak after warm-up: {peak / MIB:.1f} MiB; slope {slope * 1000 / MIB:+.2f} MiB per 1000 frames")
    print(f"growth: {100 * growth:+.2f} % (target < {100 * TARGET_GROWTH:.0f} %); {rate:.2f} frames/s")
    print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return growth


def main() -> int:
    args = _arguments()
    args.work.mkdir(parents=True, exist_ok=True)
    folder = linked_folder(synthetic_frames(args), args.frames, args.work)
    samples, status = soak(args, folder)
    if status != 0:
        print("a3d-run failed; see its stderr")
        return 2
    growth = summary(samples, args.warmup)
    passed = growth < TARGET_GROWTH
    print("PASS" if passed else "FAIL", f"memory growth {100 * growth:+.2f} % < {100 * TARGET_GROWTH:.0f} %")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
