"""Edge speed: the paper's full network, end to end through a3d-run, judged against the machine's own limit.

The paper reports 0.739 s per frame on a Titan X for the network alone. A bar in seconds says
little on CPUs whose instruction sets differ (int8 is ~4x fp32 with VNNI, ~1.5-2x on AVX2 alone), so
this benchmark measures, in the same run, what the machine can do and how close each part gets:

- the ceilings (bench.ceilings): GEMM and convolution throughput of ONNX Runtime, fp32 and int8,
  on large shapes, with the instruction set found in /proc/cpuinfo;
- a3d-run's own code (a3d.runtime.cli.run.main, i.e. a3d.runtime.pipeline) over a folder of frames,
  each run in its own process with ``--max-proposals N --save RUN.rrd`` on the first ``--frames``
  frames (the first is a warm-up, left out), with ``--overlap off``, ``on`` and ``auto``, for
  (a) the paper's network at full size: both VGG16 trunks at the native 427 x 561 input, context
      and RoI pooling, fc6/fc7 of 4096, random weights, in the ``vgg16-fused`` layout
      (a3d.train.model.config: the trunk maps fused by a 1x1 conv to 512 channels before pooling,
      so fc6 sees 2 x 512 x 7 x 7 inputs; the plain layout's fc6 alone is 1.6 GB in fp32),
      exported twice with a3d-export: fp32, and ``--svd RANK --int8`` calibrated on the first
      ``--calib-frames`` frames;
  (b) the bundled small model (``--small-model``, default the bundled live model);
  per stage (read .. rerun logging), the frame time (the period between the moments a3d-run is
  done with consecutive frames), frames/s, frames overlapped and the peak resident memory;
- the network alone on the same inputs (the runtime's front end on the same frames): ONNX Runtime
  through the runtime's DetectorModel for both files (all RoIs, one RoI) and torch eager fp32;
- ONNX Runtime's profile of each model (bench.network_profile): per part (front end, trunks,
  head, whole frame) the MACs, the time, the time at the measured ceiling and the fraction of it
  reached; and the head per operator, which shows where it loses time.

Printed last: which export is faster here (measured) and the runtime's CPU-flag advice
(a3d.runtime.network.cpu_support), then PASS/FAIL lines with the load average: int8 trunks >=
75 % of the int8 convolution ceiling; end to end <= 1.25 x the network alone; <= 0.739 s where the
CPU has int8 dot products (elsewhere the measured and the projected time at the ceiling);
``--overlap auto`` never slower than sequential for both models; ONNX Runtime fp32 >= 1.3 x
torch eager; a3d-run's peak memory with the int8 model <= 2 GiB. docs/edge-speed.md explains them.

    .venv/bin/a3d-synth /tmp/a3d_edge/synth --frames 24 --seed 11 --split test=0.5
    .venv/bin/python -m bench.edge_speed /tmp/a3d_edge/synth/test --work /tmp/a3d_edge/work \\
        [--small-model runtime/models/live.onnx] [--frames 8] [--max-proposals 500] [--svd 1024]

The checkpoint and the exports are kept in ``--work`` and reused by later runs (``--rebuild``
makes them again); building them takes about 10 minutes on 2 busy cores and up to 8.4 GB of
memory (the int8 export). ``--net cpu-eighth --svd 64 --max-proposals 100 --frames 4 --no-torch``
is a quick run of the same code on a small network.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from a3d.runtime.models import model_path
from a3d.runtime.pipeline import STAGES as PIPELINE_STAGES
from a3d.runtime.pipeline import PreparedFrame
from bench import edge_report as report
from bench.ceilings import measure_ceilings
from bench.edge_report import Measurements, NetworkResult, RunResult
from bench.network_profile import NetworkProfile, profile_network

BIN = Path(sys.executable).parent
REPO = Path(__file__).resolve().parents[1]  # where ``python -m bench.NAME`` runs


# ----------------------------------------------------------------------------- the models


def random_checkpoint(path: Path, net_preset: str, overrides: dict | None = None, seed: int = 0) -> Path:
    """An a3d-train checkpoint of a randomly initialised A3DNet of ``net_preset``, the training
    config's ``overrides`` (nested dicts) applied; for speed only: identity target statistics,
    seeded random class mean sizes."""
    import torch

    from a3d.runtime.structures.classes import CLASSES
    from a3d.train.checkpoint import save_checkpoint
    from a3d.train.config import TrainConfig, apply_values
    from a3d.train.dataset import TargetStats
    from a3d.train.model import A3DNet, preset

    config = apply_values(TrainConfig(net=preset(net_preset)), overrides or {}, "edge_speed")
    torch.manual_seed(seed)
    net = A3DNet(config.net).eval()
    sizes = np.random.default_rng(seed).uniform(0.3, 2.0, (19, 3))
    save_checkpoint(path, {
        "iteration": 0, "config": config.to_json(), "model": net.state_dict(), "optimizer": {},
        "target_stats": TargetStats.identity().to_tensors(), "mean_sizes": torch.from_numpy(sizes),
        "classes": list(CLASSES),
    })  # fmt: skip
    return path


def export_model(checkpoint: Path, out: Path, frames: Path, *, svd: int | None = None, int8: bool = False,
                 calib: Path | None = None, calib_frames: int = 4, threads: int = 2) -> float:  # fmt: skip
    """``a3d-export`` (its CLI, in a child process) verified on ``frames``; int8 calibrated on the
    first ``calib_frames`` of ``calib`` (default: ``frames``). Returns its wall seconds."""
    command = [str(BIN / "a3d-export"), str(checkpoint), "-o", str(out), "--verify-frames", str(frames),
               "--threads", str(threads)]  # fmt: skip
    if svd is not None:
        command += ["--svd", str(svd)]
    if int8:
        command += ["--int8", "--calib", str(calib or frames), "--calib-frames", str(calib_frames)]
    print("$ " + " ".join(command), file=sys.stderr, flush=True)
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def frame_subset(folder: Path, out: Path, count: int) -> Path:
    """A folder of symbolic links to the first ``count`` frames of ``folder`` (and its intrinsics)."""
    from a3d.runtime.sources.folder import INTRINSICS_FILE, list_frames

    out.mkdir(parents=True, exist_ok=True)
    keep = {ref.name for ref in list_frames(folder)[:count]}
    for path in folder.iterdir():
        if path.name == INTRINSICS_FILE or path.name.split(".")[0] in keep:
            link = out / path.name
            if not link.exists():
                link.symlink_to(path.resolve())
    return out


# ----------------------------------------------------------------------------- a3d-run, instrumented


def measure_run(model: Path, frames: Path, *, max_proposals: int, threads: int = 2, overlap: str = "off",
                rrd: Path | None = None) -> RunResult:  # fmt: skip
    """Run a3d-run's main on ``frames`` with ``model`` and time every stage of every frame.

    The pipeline's own per-frame ``timing`` gives the stages up to NMS + decoding; a3d-run reports
    its line writing and rerun logging per frame (``FrameReport``). The frame period is measured
    between the moments a3d-run is done with consecutive frames (written and logged), so that the
    period between the warm-up frame and the next holds exactly the next frame's stages: the
    warm-up frame's own writing and first rerun logging (hundreds of ms) stay out of it as they
    stay out of the stage means.
    """
    from a3d.runtime.cli import run as run_cli
    from a3d.runtime.io.detections_io import read_detections

    with tempfile.TemporaryDirectory(prefix="a3d-edge-") as tmp:
        output = Path(tmp) / "detections.jsonl"
        rrd = rrd or Path(tmp) / "run.rrd"
        argv = [str(frames), "--model", str(model), "--output", str(output), "--threads", str(threads),
                "--max-proposals", str(max_proposals), "--save", str(rrd), "--overlap", overlap]  # fmt: skip
        reports: list[tuple[float, run_cli.FrameReport]] = []
        code = run_cli.main(argv, on_frame=lambda report: reports.append((time.perf_counter(), report)))
        if code != 0:
            raise RuntimeError(f"a3d-run {' '.join(argv)} exited with {code}")
        lines = read_detections(output)
    if len(lines) != len(reports):
        raise RuntimeError(f"a3d-run wrote {len(lines)} lines for {len(reports)} frames")
    skip = 1 if len(lines) > 1 else 0  # the first frame warms up ONNX Runtime's memory arena and rerun
    stages = {s: float(np.mean([line.timing.get(s, 0.0) for line in lines[skip:]])) for s in PIPELINE_STAGES}
    stages["output"] = float(np.mean([r.output_seconds for _, r in reports[skip:]]))
    stages["rerun"] = float(np.mean([r.log_seconds for _, r in reports[skip:]]))
    done = [moment for moment, _ in reports]
    period = (done[-1] - done[0]) / (len(done) - 1) if len(done) > 1 else lines[0].timing["total"]
    rois = [len(r.outcome.prepared.rois) if r.outcome.prepared is not None else 0 for _, r in reports]
    overlapped = sum(r.outcome.overlapped for _, r in reports)
    return RunResult(model.name, overlap, len(lines), float(np.mean(rois)), stages, period, overlapped)


# ----------------------------------------------------------------------------- the network alone


def network_inputs(
    model: Path, frames: Path, max_proposals: int, count: int | None = None
) -> list[PreparedFrame]:
    """What a3d-run feeds ``model`` for each (of the first ``count``) frame of ``frames``
    (a3d.runtime.pipeline.prepare; a3d.export.verify.folder_inputs does the same but brings torch
    into the process)."""
    from a3d.runtime.network.model import DetectorModel
    from a3d.runtime.pipeline import PipelineConfig, load_and_prepare
    from a3d.runtime.sources.folder import FolderSource

    metadata = DetectorModel.load(model, threads=1).metadata
    config = PipelineConfig.from_metadata(metadata, max_proposals=max_proposals)
    return [load_and_prepare(loader, config) for loader in itertools.islice(FolderSource(frames), count)]


def measure_ort(model: Path, frames: Path, *, max_proposals: int, threads: int = 2) -> NetworkResult:
    """ONNX Runtime through the runtime's DetectorModel (its session options and threads)."""
    from a3d.runtime.network.model import DetectorModel

    inputs = network_inputs(model, frames, max_proposals)
    detector = DetectorModel.load(model, threads=threads)
    return _network_result("onnxruntime", model.name, detector.run, inputs)


def measure_torch(checkpoint: Path, frames: Path, model: Path, *, max_proposals: int,
                  threads: int = 2) -> NetworkResult:  # fmt: skip
    """Torch eager fp32 (a3d.train.inference.TorchNetwork) of ``checkpoint`` on the inputs a3d-run
    feeds ``model`` (its fp32 export)."""
    import torch

    from a3d.train.checkpoint import load_trained
    from a3d.train.inference import TorchNetwork

    torch.set_num_threads(threads)
    inputs = network_inputs(model, frames, max_proposals)
    trained = load_trained(checkpoint)
    network = TorchNetwork(trained.net, trained.stats, trained.config.inference.regress_3d)
    return _network_result("torch eager", checkpoint.name, network.run, inputs)


def _network_result(engine: str, model: str, run: Callable, inputs: list[PreparedFrame]) -> NetworkResult:
    used = [i for i in inputs if len(i.rois)]
    if not used:
        raise RuntimeError("no frame with a usable proposal")
    run(used[0].color_input, used[0].depth_input, used[0].rois, used[0].context_rois)  # warm-up
    full, one = [], []
    for item in used:
        for seconds, count in ((full, len(item.rois)), (one, 1)):
            start = time.perf_counter()
            run(item.color_input, item.depth_input, item.rois[:count], item.context_rois[:count])
            seconds.append(time.perf_counter() - start)
    return NetworkResult(engine, model, float(np.mean(full)), float(np.mean(one)),
                         float(np.mean([len(i.rois) for i in used])))  # fmt: skip


def measure_profile(model: Path, frames: Path, *, max_proposals: int, threads: int = 2) -> NetworkProfile:
    """ONNX Runtime's per-operator profile of ``model`` (bench.network_profile) on the frame with
    the most RoIs among the first two of ``frames``."""
    inputs = [i for i in network_inputs(model, frames, max_proposals, count=2) if len(i.rois) >= 2]
    if not inputs:
        raise RuntimeError(f"{frames}: no frame with 2 usable proposals among the first two")
    item = max(inputs, key=lambda i: len(i.rois))
    feeds = {"color": item.color_input, "depth": item.depth_input, "rois": item.rois,
             "context_rois": item.context_rois}  # fmt: skip
    return profile_network(model, feeds, threads)


# ----------------------------------------------------------------------------- child processes


WORKERS: dict[str, Callable] = {
    "run": measure_run, "ort": measure_ort, "torch": measure_torch, "profile": measure_profile
}  # fmt: skip


def in_child(kind: str, **kwargs) -> dict:
    """``WORKERS[kind](**kwargs)`` in a fresh Python process; its result as a dict, with the
    child's peak resident memory (``peak_bytes``)."""
    with tempfile.TemporaryDirectory(prefix="a3d-edge-") as tmp:
        spec, result = Path(tmp) / "spec.json", Path(tmp) / "result.json"
        spec.write_text(
            json.dumps({k: str(v.resolve()) if isinstance(v, Path) else v for k, v in kwargs.items()})
        )
        subprocess.run([sys.executable, "-m", "bench.edge_speed", "--worker", kind, str(spec), str(result)],
                       check=True, cwd=REPO)  # fmt: skip
        return json.loads(result.read_text())


def peak_resident_bytes() -> int:
    """This process's peak resident memory: VmHWM, which starts afresh at exec. (getrusage's
    ru_maxrss survives exec, so a child would report the parent's peak when that is higher: the
    ceilings' 600 MB of test matrices, a checkpoint built in the parent.)"""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024  # kB
    raise RuntimeError("no VmHWM in /proc/self/status")


def _worker(kind: str, spec: Path, result: Path) -> None:
    kwargs = json.loads(spec.read_text())
    paths = {"model", "frames", "checkpoint", "rrd"}
    kwargs = {k: Path(v) if k in paths and v is not None else v for k, v in kwargs.items()}
    value = asdict(WORKERS[kind](**kwargs))
    value["peak_bytes"] = peak_resident_bytes()
    result.write_text(json.dumps(value))


# ----------------------------------------------------------------------------- main


def build_full_model(work: Path, frames: Path, args: argparse.Namespace) -> tuple[Path, Path, Path]:
    """The checkpoint of ``args.net`` and its fp32 and int8 + SVD exports in ``work`` (kept between runs)."""
    checkpoint = work / args.net / "checkpoint.pt"
    fp32, int8 = work / f"{args.net}.fp32.onnx", work / f"{args.net}.svd{args.svd}.int8.onnx"
    if args.rebuild or not checkpoint.is_file():
        start = time.perf_counter()
        random_checkpoint(checkpoint, args.net, {"proposals": {"max_proposals": args.max_proposals}})
        print(f"checkpoint {checkpoint}: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    for out, options in ((fp32, {}), (int8, {"svd": args.svd, "int8": True})):
        if args.rebuild or not out.is_file():
            seconds = export_model(checkpoint, out, frames, calib_frames=args.calib_frames,
                                   threads=args.threads, **options)  # fmt: skip
            print(f"export {out.name}: {seconds:.0f} s", file=sys.stderr)
    return checkpoint, fp32, int8


def measure(args: argparse.Namespace, frames: Path, checkpoint: Path, fp32: Path, int8: Path) -> Measurements:
    """Every measurement, each in its own process (module docstring), the ceilings first and last
    (each ceiling the higher of the two). The a3d-run modes, the int8 network alone and its
    profile each run in ``args.processes`` processes, one of each per round, so that the rounds'
    profiles are minutes apart; the fastest of each is kept. The machine switches between two
    speeds for seconds to minutes at a time (docs/edge-speed.md "Closing numbers, part five"),
    which one process per mode, or back-to-back processes, would compare instead of the code."""
    m = Measurements(ceiling_runs=[measure_ceilings(args.threads)])
    common = {"frames": frames, "max_proposals": args.max_proposals, "threads": args.threads}
    full: dict[str, RunResult] = {}
    small: dict[str, RunResult] = {}
    networks: list[NetworkResult] = []
    for _ in range(args.processes):
        for overlap in report.MODES:
            rrd = args.work / f"{int8.stem}.{overlap}.rrd"
            _keep_faster(
                full, overlap, RunResult(**in_child("run", model=int8, overlap=overlap, rrd=rrd, **common))
            )
            if args.small_model.is_file():
                run = RunResult(**in_child("run", model=args.small_model, overlap=overlap, **common))
                _keep_faster(small, overlap, run)
        networks.append(NetworkResult(**in_child("ort", model=int8, **common)))
        m.int8_profiles.append(NetworkProfile.from_dict(in_child("profile", model=int8, **common)))
    m.full, m.small = [full[o] for o in report.MODES], [small[o] for o in report.MODES if o in small]
    m.networks["ort int8 + SVD"] = min(networks, key=lambda n: n.seconds)
    m.networks["ort fp32"] = NetworkResult(**in_child("ort", model=fp32, **common))
    if not args.no_torch:
        m.networks["torch eager fp32"] = NetworkResult(**in_child("torch", checkpoint=checkpoint, model=fp32,
                                                                  **common))  # fmt: skip
    m.profiles["int8 + SVD"] = min(m.int8_profiles, key=lambda p: p.seconds("trunks") + p.seconds("head"))
    m.profiles["fp32"] = NetworkProfile.from_dict(in_child("profile", model=fp32, **common))
    if m.small:
        m.networks["ort small model"] = NetworkResult(**in_child("ort", model=args.small_model, **common))
        m.profiles["small model"] = NetworkProfile.from_dict(
            in_child("profile", model=args.small_model, **common)
        )
    m.ceiling_runs.append(measure_ceilings(args.threads))  # again: a busy machine shows as a spread
    return m


def _keep_faster(runs: dict[str, RunResult], overlap: str, run: RunResult) -> None:
    """``runs[overlap]``: the run with the shorter frame time of the one there and ``run``."""
    if overlap not in runs or run.frame_seconds < runs[overlap].frame_seconds:
        runs[overlap] = run


def print_report(m: Measurements, args: argparse.Namespace, int8: Path) -> None:
    """Everything measured (bench.edge_report), the targets last."""
    report.print_ceilings(m.ceiling_runs)
    report.print_breakdown(f"(a) {int8} through a3d-run", m.full, m.networks["ort int8 + SVD"])
    if m.small:
        report.print_breakdown(
            f"(b) {args.small_model} through a3d-run", m.small, m.networks["ort small model"]
        )
    elif not args.small_model.is_file():
        print(f"\n(b) skipped: no {args.small_model}")
    report.print_networks(m.networks)
    runs = {"int8 + SVD": m.full[0], "fp32": None, "small model": m.small[0] if m.small else None}
    for name, profile in m.profiles.items():
        report.print_parts(f"{name} ({profile.model})", profile, m.ceilings, runs[name])
    for name, profile in m.profiles.items():
        report.print_head_ops(f"{name} ({profile.model})", profile, m.ceilings)
    report.print_export_choice(m.networks)
    report.print_targets(m)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.edge_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("frames", type=Path, help="frames (427 x 561: a3d-synth's test split)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/a3d_edge_speed"), help="checkpoint, models")
    parser.add_argument("--small-model", type=Path, default=model_path("live"))
    parser.add_argument("--frames", dest="count", type=int, default=8, help="frames per run (1 warm-up)")
    parser.add_argument("--max-proposals", type=int, default=500)
    parser.add_argument("--net", default="vgg16-fused", help="network preset of (a) (a3d.train.model.config)")
    parser.add_argument("--svd", type=int, default=1024, help="fc6/fc7 SVD rank of the int8 model")
    parser.add_argument("--calib-frames", type=int, default=4)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rebuild", action="store_true", help="make the checkpoint and exports again")
    parser.add_argument("--no-torch", action="store_true", help="skip the torch eager comparison")
    parser.add_argument(
        "--processes",
        type=int,
        default=3,
        help="processes per a3d-run mode, int8 network, profile: the fastest",
    )
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    frames = frame_subset(args.frames, args.work / "frames", args.count)
    checkpoint, fp32, int8 = build_full_model(args.work, frames, args)
    print(
        f"edge speed: {args.count} frames of {args.frames}, --max-proposals {args.max_proposals}, "
        f"--threads {args.threads}, the fastest of {args.processes} processes per a3d-run mode, int8 network "
        f"and profile; {report.cpu_description()}; {report.load_average()} at the start",
        flush=True,
    )
    m = measure(args, frames, checkpoint, fp32, int8)
    print_report(m, args, int8)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--worker":
        _worker(sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4]))
    else:
        sys.exit(main())
