"""Statistics of a synthetic set against the NYUv2-like targets (a3d.synth.stats).

Either summarise a set written by ``a3d-synth`` (its ``synth_objects.jsonl``), or render
``--frames N`` frames in memory (seeds as a3d-synth would use with ``--seed S``) and summarise:

    .venv/bin/a3d-synth /tmp/synth1000 --frames 1000 --seed 0 --workers 2
    .venv/bin/python -m bench.synth_stats /tmp/synth1000
    .venv/bin/python -m bench.synth_stats --frames 100 --seed 0 [--world real]

``--world real`` renders with that world's defaults (a3d.synth.cli.WORLDS: clutter, camera mix,
real light, rooms without class objects), frame by frame as a3d-synth would.
"""

import argparse
from pathlib import Path

from tqdm import tqdm

from a3d.synth import SceneConfig, generate_frame
from a3d.synth.cli import WORLDS, frame_configs, frame_seed
from a3d.synth.stats import format_summary, frame_record, read_records, summarise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, help="a folder written by a3d-synth")
    parser.add_argument("--frames", type=int, default=100, help="frames to render when no folder is given")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--world", choices=tuple(WORLDS), default="a3d")
    args = parser.parse_args()
    if args.folder is not None:
        records = read_records(args.folder)
    else:
        world = WORLDS[args.world]
        scene = SceneConfig(clutter=world["clutter"], real_light=world["real_light"])
        configs = frame_configs(args.seed, args.frames, scene, world["camera_mix"], 1.0, world["empty_share"])
        records = []
        for i, config in enumerate(tqdm(configs, unit="frame")):
            seed = frame_seed(args.seed, i)
            records.append(frame_record(f"synth_{i:06d}", "-", seed, generate_frame(seed, config)))
    print(format_summary(summarise(records)))


if __name__ == "__main__":
    main()
