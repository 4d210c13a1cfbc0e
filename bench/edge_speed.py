"""Edge speed: the paper's full network, end to end through a3d-run, on 2 CPU cores.

The paper reports 0.739 s per frame on a Titan X for the network alone. This benchmark times
a3d-run's own code (a3d.runtime.cli.run.main, i.e. a3d.runtime.pipeline) over a folder of
frames, with

(a) the paper's network at full size: both VGG16 trunks at the native 427 x 561 input, context
    and RoI pooling, fc6/fc7 of 4096, random weights. The layout is the ``vgg16-fused``
    preset (a3d.train.model.config): the trunk maps are fused by a 1x1 conv to 512 channels
    before pooling, so fc6 sees 2 x 512 x 7 x 7 inputs instead of the plain layout's
    4 x 512 x 7 x 7 (whose fc6 alone is 100352 x 4096 weights, 1.6 GB in fp32); it is the
    layout docs/platform.md measured. The checkpoint is written with a3d.train.checkpoint and
    exported with a3d-export twice: fp32 (no SVD), and ``--svd RANK --int8`` calibrated on the
    first ``--calib-frames`` frames;
(b) the bundled small model (``--small-model``, default samples/model.onnx when it exists).

Every a3d-run measurement runs in its own process (so that its peak resident memory is a3d-run's)
with ``--max-proposals N --save RUN.rrd`` on the first ``--frames`` frames, sequential and with
``--overlap``. The first frame is a warm-up and is left out. Printed per run: the per-stage
mean seconds (read, hole fill, gravity, proposals, lifting, network input, the ONNX Runtime call,
NMS + decoding, output writing = JSON formatting + the flushed and fsynced line, rerun logging
= the synchronous part of logging the frame; rerun encodes and writes the .rrd on its own
threads, which the frame time includes), the frame time (steady-state period between frames),
frames/s and the peak resident memory.

Network alone, on the same inputs (the runtime's front end on the same frames), each in its own
process: ONNX Runtime (a3d.runtime.network.model.DetectorModel, the runtime's own session) for the fp32
and int8 + SVD files, with all RoIs and with one RoI (about the trunks' share; the head is the
difference), and torch eager fp32 (a3d.train.inference.TorchNetwork, the same checkpoint, same
thread count). Times move between machines and with the load, so the targets are also ratios:

- int8 + SVD end to end <= 1.3 x its ONNX Runtime network call alone, and <= 0.739 s per frame;
- ONNX Runtime fp32 >= 1.3 x faster than torch eager fp32 (same model, same inputs);
- peak resident memory of a3d-run with the int8 model <= 2 GiB.

    .venv/bin/a3d-synth /tmp/a3d_edge/synth --frames 24 --seed 11 --split test=0.5
    .venv/bin/python -m bench.edge_speed /tmp/a3d_edge/synth/test --work /tmp/a3d_edge/work \\
        [--small-model samples/model.onnx] [--frames 8] [--max-proposals 500] [--svd 1024]

The checkpoint and the exports are kept in ``--work`` and reused by later runs (``--rebuild``
makes them again); building them takes about 10 minutes on 2 busy cores and up to 8.4 GB of
memory (the int8 export). The first line says whether the CPU has VNNI: without it ONNX Runtime's
int8 trunks gain 1.9-2.7x over fp32 (measured on an AVX2-only VM) instead of docs/platform.md's 3.8x.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from a3d.runtime.pipeline import STAGES as PIPELINE_STAGES
from a3d.runtime.pipeline import PreparedFrame

BIN = Path(sys.executable).parent
REPO = Path(__file__).resolve().parents[1]  # where ``python -m bench.NAME`` runs
PAPER_SECONDS = 0.739  # Deng & Latecki 2017, Titan X, network only
TARGET_E2E_OVER_NETWORK = 1.3
TARGET_ORT_OVER_TORCH = 1.3
TARGET_PEAK_BYTES = 2 * 1024**3
RUN_STAGES = (*PIPELINE_STAGES, "output", "rerun")
STAGE_LABELS = {
    "read": "read",
    "depth_fill": "hole fill",
    "gravity": "gravity",
    "proposals": "proposals",
    "lifting": "lifting",
    "network_input": "network input",
    "network": "ORT network",
    "postprocess": "NMS + decoding",
    "output": "output writing",
    "rerun": "rerun logging",
}


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


@dataclass
class RunResult:
    """One a3d-run over a folder: mean seconds per stage (warm-up frame left out), the
    steady-state frame period, the mean RoIs per frame and the process's peak resident memory."""

    model: str
    overlap: bool
    frames: int
    rois: float
    stages: dict[str, float]
    frame_seconds: float
    peak_bytes: int = 0

    @property
    def stage_sum(self) -> float:
        return sum(self.stages.values())


def measure_run(model: Path, frames: Path, *, max_proposals: int, threads: int = 2, overlap: bool = False,
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
                "--max-proposals", str(max_proposals), "--save", str(rrd)]  # fmt: skip
        if overlap:
            argv.append("--overlap")
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
    return RunResult(model.name, overlap, len(lines), float(np.mean(rois)), stages, period)


# ----------------------------------------------------------------------------- the network alone


def network_inputs(model: Path, frames: Path, max_proposals: int) -> list[PreparedFrame]:
    """What a3d-run feeds ``model`` for each frame of ``frames`` (a3d.runtime.pipeline.prepare;
    a3d.export.verify.folder_inputs does the same but brings torch into the process)."""
    from a3d.runtime.network.model import DetectorModel
    from a3d.runtime.pipeline import PipelineConfig, load_and_prepare
    from a3d.runtime.sources.folder import FolderSource

    metadata = DetectorModel.load(model, threads=1).metadata
    config = PipelineConfig.from_metadata(metadata, max_proposals=max_proposals)
    return [load_and_prepare(loader, config) for loader in FolderSource(frames)]


@dataclass
class NetworkResult:
    """Mean seconds per frame (warm-up call left out) of the network with all RoIs and with one
    RoI (the trunks plus a one-RoI head), the mean RoIs, and the process's peak resident memory."""

    engine: str
    model: str
    seconds: float
    one_roi_seconds: float
    rois: float
    peak_bytes: int = 0

    @property
    def head_seconds(self) -> float:
        return self.seconds - self.one_roi_seconds


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

    from a3d.export.onnx_export import load_trained
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


# ----------------------------------------------------------------------------- child processes


WORKERS: dict[str, Callable] = {"run": measure_run, "ort": measure_ort, "torch": measure_torch}


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


def _worker(kind: str, spec: Path, result: Path) -> None:
    kwargs = json.loads(spec.read_text())
    paths = {"model", "frames", "checkpoint", "rrd"}
    kwargs = {k: Path(v) if k in paths and v is not None else v for k, v in kwargs.items()}
    value = asdict(WORKERS[kind](**kwargs))
    value["peak_bytes"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
    result.write_text(json.dumps(value))


# ----------------------------------------------------------------------------- report


@dataclass
class Measurements:
    """Everything one benchmark run measured: a3d-run with the full model's int8 + SVD file and
    with the small model (sequential, then --overlap), and the networks alone."""

    full: list[RunResult] = field(default_factory=list)
    small: list[RunResult] = field(default_factory=list)
    networks: dict[str, NetworkResult] = field(default_factory=dict)


def print_breakdown(title: str, runs: list[RunResult], network: NetworkResult | None = None) -> None:
    """One column per run: stage means, their sum, the frame period, frames/s, peak memory; the
    network stage split into trunks and head by ``network``'s one-RoI share."""
    print(f"\n{title}")
    print(
        f"  {'ms per frame':30s}"
        + "".join(f"{'--overlap' if r.overlap else 'sequential':>12s}" for r in runs)
    )
    rows = [(STAGE_LABELS[s], [1e3 * r.stages[s] for r in runs]) for s in RUN_STAGES]
    if network is not None:
        share = network.one_roi_seconds / network.seconds
        at = RUN_STAGES.index("network") + 1
        network_ms = [1e3 * r.stages["network"] for r in runs]
        rows[at:at] = [
            ("  trunks (est.)", [share * ms for ms in network_ms]),
            ("  head (est.)", [(1 - share) * ms for ms in network_ms]),
        ]
    rows += [
        ("sum of stages", [1e3 * r.stage_sum for r in runs]),
        ("frame time", [1e3 * r.frame_seconds for r in runs]),
        ("other (< 0: hidden by overlap)", [1e3 * (r.frame_seconds - r.stage_sum) for r in runs]),
        ("frames/s", [1 / r.frame_seconds for r in runs]),
        ("RoIs per frame", [r.rois for r in runs]),
        ("peak resident memory (MiB)", [r.peak_bytes / 2**20 for r in runs]),
    ]
    for label, values in rows:
        print(
            f"  {label:30s}" + "".join(f"{v:12.2f}" if label == "frames/s" else f"{v:12.1f}" for v in values)
        )


def print_networks(networks: dict[str, NetworkResult]) -> None:
    print("\nnetwork alone, same inputs (ms per frame; trunks ~ the one-RoI call, head = the rest)")
    print(f"  {'':28s}{'all RoIs':>10s}{'trunks':>10s}{'head':>10s}{'RoIs':>8s}{'peak MiB':>10s}")
    for key, n in networks.items():
        print(f"  {key:28s}{1e3 * n.seconds:10.1f}{1e3 * n.one_roi_seconds:10.1f}"
              f"{1e3 * n.head_seconds:10.1f}{n.rois:8.0f}{n.peak_bytes / 2**20:10.0f}")  # fmt: skip


def print_targets(m: Measurements) -> None:
    """Ratios, then a PASS/FAIL line per target (the faster a3d-run mode of the full model)."""
    best = min(m.full, key=lambda r: r.frame_seconds)
    mode = "--overlap" if best.overlap else "sequential"
    alone = m.networks["ort int8 + SVD"].seconds
    fp32 = m.networks["ort fp32"].seconds
    torch_fp32 = m.networks["torch eager fp32"].seconds if "torch eager fp32" in m.networks else None
    print("\nratios (machine independent)")
    print(f"  end to end ({mode}) / network alone, int8 + SVD: {best.frame_seconds / alone:.2f}")
    print(f"  int8 + SVD / fp32, ONNX Runtime network: {alone / fp32:.2f}")
    if torch_fp32 is not None:
        print(f"  ONNX Runtime fp32 / torch eager fp32 network: {fp32 / torch_fp32:.2f}")
    print(f"\ntargets ({load_average()} now)")
    _target(f"int8 + SVD end to end <= {TARGET_E2E_OVER_NETWORK} x its network alone",
            best.frame_seconds <= TARGET_E2E_OVER_NETWORK * alone,
            f"{best.frame_seconds:.3f} s vs {TARGET_E2E_OVER_NETWORK} x {alone:.3f} s ({mode})")  # fmt: skip
    _target(f"int8 + SVD end to end <= {PAPER_SECONDS} s (the paper: Titan X, network only)",
            best.frame_seconds <= PAPER_SECONDS, f"{best.frame_seconds:.3f} s a frame ({mode})")  # fmt: skip
    if torch_fp32 is not None:
        speedup = torch_fp32 / fp32
        _target(f"ONNX Runtime fp32 >= {TARGET_ORT_OVER_TORCH} x faster than torch eager fp32",
                speedup >= TARGET_ORT_OVER_TORCH, f"{speedup:.2f} x")  # fmt: skip
    peak = max(r.peak_bytes for r in m.full)
    _target("peak resident memory of a3d-run with the int8 model <= 2 GiB", peak <= TARGET_PEAK_BYTES,
            f"{peak / 2**30:.2f} GiB")  # fmt: skip


def _target(what: str, ok: bool, detail: str) -> None:
    print(f"  [{'PASS' if ok else 'FAIL'}] {what}: {detail}")


def load_average() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} CPUs"


def cpu_description() -> str:
    """The CPU model and whether it has the int8 dot-product instructions ONNX Runtime's int8 path
    uses (VNNI); without them int8 gains far less over fp32 (docs/platform.md measured with them)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "unknown CPU"
    pairs = (line.split(":", 1) for line in reversed(text.splitlines()) if ":" in line)
    fields = {key.strip(): value.strip() for key, value in pairs}  # the first CPU's values win
    model = fields.get("model name", "unknown CPU")
    flags = set(fields.get("flags", "").split())
    isa = [name for name in ("avx2", "avx512f", "avx512_vnni", "avx_vnni", "amx_int8") if name in flags]
    return f"{model} ({', '.join(isa) or 'no AVX2'})"


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
    """Every measurement, each in its own process (module docstring)."""
    m = Measurements()
    common = {"frames": frames, "max_proposals": args.max_proposals, "threads": args.threads}
    for overlap in (False, True):
        rrd = args.work / f"{int8.stem}{'.overlap' * overlap}.rrd"
        m.full.append(RunResult(**in_child("run", model=int8, overlap=overlap, rrd=rrd, **common)))
        if args.small_model.is_file():
            m.small.append(RunResult(**in_child("run", model=args.small_model, overlap=overlap, **common)))
    m.networks["ort int8 + SVD"] = NetworkResult(**in_child("ort", model=int8, **common))
    m.networks["ort fp32"] = NetworkResult(**in_child("ort", model=fp32, **common))
    if not args.no_torch:
        m.networks["torch eager fp32"] = NetworkResult(**in_child("torch", checkpoint=checkpoint, model=fp32,
                                                                  **common))  # fmt: skip
    if m.small:
        m.networks["ort small model"] = NetworkResult(**in_child("ort", model=args.small_model, **common))
    return m


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("frames", type=Path, help="frames (427 x 561: a3d-synth's test split)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/a3d_edge_speed"), help="checkpoint, models")
    parser.add_argument("--small-model", type=Path, default=Path("samples/model.onnx"))
    parser.add_argument("--frames", dest="count", type=int, default=8, help="frames per run (1 warm-up)")
    parser.add_argument("--max-proposals", type=int, default=500)
    parser.add_argument("--net", default="vgg16-fused", help="network preset of (a) (a3d.train.model.config)")
    parser.add_argument("--svd", type=int, default=1024, help="fc6/fc7 SVD rank of the int8 model")
    parser.add_argument("--calib-frames", type=int, default=4)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rebuild", action="store_true", help="make the checkpoint and exports again")
    parser.add_argument("--no-torch", action="store_true", help="skip the torch eager comparison")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    frames = frame_subset(args.frames, args.work / "frames", args.count)
    checkpoint, fp32, int8 = build_full_model(args.work, frames, args)
    print(
        f"edge speed: {args.count} frames of {args.frames}, --max-proposals {args.max_proposals}, "
        f"--threads {args.threads}; {cpu_description()}; {load_average()} at the start",
        flush=True,
    )
    m = measure(args, frames, checkpoint, fp32, int8)
    print_breakdown(f"(a) {int8} through a3d-run", m.full, m.networks["ort int8 + SVD"])
    if m.small:
        print_breakdown(f"(b) {args.small_model} through a3d-run", m.small, m.networks["ort small model"])
    elif not args.small_model.is_file():
        print(f"\n(b) skipped: no {args.small_model}")
    print_networks(m.networks)
    print_targets(m)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--worker":
        _worker(sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4]))
    else:
        sys.exit(main())
