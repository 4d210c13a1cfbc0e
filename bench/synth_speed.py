"""a3d.synth rendering speed on ONE core: frames/s at the NYUv2 crop size (427 x 561).

Thread pools are limited to one thread before numpy and OpenCV load, then one warm-up frame and
``--frames`` timed frames are rendered; prints frames/s, the mean and worst seconds per frame and
the machine's load average (other processes on the machine slow the timing down).

    .venv/bin/python -m bench.synth_speed [--frames 20] [--first-seed 0]
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402

from a3d.synth import SceneConfig, generate_frame  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    config = SceneConfig()
    generate_frame(10**6, config)  # warm-up: imports, caches
    times = []
    cpu = time.process_time()
    for seed in range(args.first_seed, args.first_seed + args.frames):
        t = time.perf_counter()
        generate_frame(seed, config)
        times.append(time.perf_counter() - t)
    cpu = time.process_time() - cpu
    H, W = config.image_size
    print(
        f"{args.frames} frames at {H}x{W}, one thread: {args.frames / sum(times):.2f} frames/s "
        f"(mean {sum(times) / len(times):.3f} s, worst {max(times):.3f} s; "
        f"CPU time {cpu / args.frames:.3f} s/frame; load average {os.getloadavg()[0]:.1f})"
    )


if __name__ == "__main__":
    main()
