"""What bench.edge_speed measures and prints: the result records (a3d-run's stages, the network
alone), each part against the machine's measured ceiling, where the head's time goes, and the
PASS/FAIL targets. It imports nothing from bench.edge_speed, which imports it."""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field
from pathlib import Path

from a3d.runtime.network.cpu_support import INT8_DOT_PRODUCT, cpu_flags, export_advice
from a3d.runtime.pipeline import FRONT_END_STAGES, OVERLAP_NOISE
from a3d.runtime.pipeline import STAGES as PIPELINE_STAGES
from bench.ceilings import CONV, GEMM, Ceilings
from bench.network_profile import PARTS, NetworkProfile

PAPER_SECONDS = 0.739  # Deng & Latecki 2017, Titan X, network only
TARGET_E2E_OVER_NETWORK = 1.25
TARGET_TRUNKS_OF_CEILING = 0.75
TARGET_POOLING_SECONDS = 0.025  # both maps at 500 RoIs (the head less fc6, fc7 and the outputs)
TARGET_ORT_OVER_TORCH = 1.3
TARGET_PEAK_BYTES = 2 * 1024**3
RUN_STAGES = (*PIPELINE_STAGES, "output", "rerun")
STAGE_LABELS = {
    "read": "read",
    "depth_fill": "hole fill",
    "gravity": "gravity",
    "proposals": "proposals",
    "lifting": "lifting",
    "detector2d": "2D detector (waited for)",
    "classifier2d": "image classifier",
    "network_input": "network input",
    "network": "ORT network",
    "postprocess": "NMS + decoding",
    "output": "output writing",
    "rerun": "rerun logging",
}
ISA_FLAGS = ("avx2", "avx512f", *INT8_DOT_PRODUCT, "amx_tile", "amx_bf16")
MODES = {"off": "sequential", "on": "--overlap on", "auto": "--overlap auto"}


@dataclass
class RunResult:
    """One a3d-run over a folder: mean seconds per stage (warm-up frame left out), the
    steady-state frame period, the mean RoIs per frame and the process's peak resident memory."""

    model: str
    overlap: str  # a3d-run's --overlap: off (sequential), on, auto
    frames: int
    rois: float
    stages: dict[str, float]
    frame_seconds: float
    overlapped: int = 0  # frames prepared in the background (auto: 0 where it chose sequential)
    peak_bytes: int = 0

    @property
    def stage_sum(self) -> float:
        return sum(self.stages.values())

    @property
    def front_end_seconds(self) -> float:
        return sum(self.stages[s] for s in FRONT_END_STAGES)


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


@dataclass
class Measurements:
    """Everything one benchmark run measured: the ceilings; a3d-run with the full model's int8 +
    SVD file and with the small model (--overlap off, on, auto); the networks alone; profiles."""

    ceiling_runs: list[Ceilings] = field(default_factory=list)  # at the start and at the end
    full: list[RunResult] = field(default_factory=list)
    small: list[RunResult] = field(default_factory=list)
    networks: dict[str, NetworkResult] = field(default_factory=dict)
    profiles: dict[str, NetworkProfile] = field(default_factory=dict)
    int8_profiles: list[NetworkProfile] = field(default_factory=list)  # one a round; the fastest in profiles

    @property
    def ceilings(self) -> Ceilings:
        """Each ceiling's best measurement in the run."""
        return functools.reduce(Ceilings.best, self.ceiling_runs)


def load_average() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} CPUs"


def cpu_description() -> str:
    """The CPU model and the instruction-set flags that decide ONNX Runtime's int8 speed."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "unknown CPU"
    names = [line.split(":", 1)[1].strip() for line in text.splitlines() if line.startswith("model name")]
    model = names[0] if names else "unknown CPU"
    flags = cpu_flags(text)
    return f"{model} ({', '.join(f for f in ISA_FLAGS if f in flags) or 'no AVX2'})"


def print_ceilings(runs: list[Ceilings]) -> None:
    """The ceilings as measured at the start and at the end of the run (their spread shows how
    disturbed the machine was); the parts are judged against the higher of each."""
    m, k, n = GEMM
    c_in, c_out, h, w = CONV
    print(f"\nthis machine's ceilings through ONNX Runtime, {runs[0].threads} threads (GMAC/s, start / end)")
    print(f"  {'':40s}{'fp32':>14s}{'int8':>14s}{'int8/fp32':>11s}")
    for label, kind in (
        (f"GEMM {m} x {k} x {n}", "gemm"),
        (f"conv 3x3 {c_in} -> {c_out} on {h} x {w}", "conv"),
    ):
        fp32, int8 = ([getattr(c, f"{kind}_{p}") / 1e9 for c in runs] for p in ("fp32", "int8"))
        shown = ["/".join(f"{v:.1f}" for v in values) for values in (fp32, int8)]
        print(f"  {label:40s}{shown[0]:>14s}{shown[1]:>14s}{max(int8) / max(fp32):11.2f}")
    best = functools.reduce(Ceilings.best, runs)
    if not cpu_flags() & set(INT8_DOT_PRODUCT):
        low, high = sorted((best.conv_int8 / best.conv_fp32, best.gemm_int8 / best.gemm_fp32))
        gains = f"{low:.1f}-{high:.1f}x"
        print(f"  no int8 dot-product instructions ({', '.join(INT8_DOT_PRODUCT[:3])}): ONNX Runtime's int8 "
              f"reaches {gains} fp32 here, about 3-4x with VNNI")  # fmt: skip


def print_breakdown(title: str, runs: list[RunResult], network: NetworkResult | None = None) -> None:
    """One column per run: stage means, their sum, the frame period, frames/s, peak memory; the
    network stage split into trunks and head by ``network``'s one-RoI share."""
    print(f"\n{title}")
    print(f"  {'ms per frame':30s}" + "".join(f"{MODES[r.overlap]:>16s}" for r in runs))
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
        ("frames prepared in background", [r.overlapped for r in runs]),
        ("RoIs per frame", [r.rois for r in runs]),
        ("peak resident memory (MiB)", [r.peak_bytes / 2**20 for r in runs]),
    ]
    for label, values in rows:
        print(
            f"  {label:30s}" + "".join(f"{v:16.2f}" if label == "frames/s" else f"{v:16.1f}" for v in values)
        )


def print_networks(networks: dict[str, NetworkResult]) -> None:
    print("\nnetwork alone, same inputs (ms per frame; trunks ~ the one-RoI call, head = the rest)")
    print(f"  {'':28s}{'all RoIs':>10s}{'trunks':>10s}{'head':>10s}{'RoIs':>8s}{'peak MiB':>10s}")
    for key, n in networks.items():
        print(f"  {key:28s}{1e3 * n.seconds:10.1f}{1e3 * n.one_roi_seconds:10.1f}"
              f"{1e3 * n.head_seconds:10.1f}{n.rois:8.0f}{n.peak_bytes / 2**20:10.0f}")  # fmt: skip


def print_parts(title: str, profile: NetworkProfile, c: Ceilings, run: RunResult | None = None) -> None:
    """Per part: MACs, time, the time at the ceiling of each op's kind and precision, the fraction
    of the ceiling reached; the network from the profile, the front end and frame from ``run``."""
    print(f"\n{title}: per part, {profile.rois} RoIs (ORT profile, median of {profile.calls} calls)")
    print(f"  {'':34s}{'GMAC':>8s}{'ms':>9s}{'ms at ceiling':>15s}{'of ceiling':>12s}")
    rows = [
        (part, profile.macs(part), profile.seconds(part), profile.seconds_at_ceiling(part, c))
        for part in PARTS
    ]
    network = ("network (trunks + head)", *(sum(r[i] for r in rows) for i in (1, 2, 3)))
    rows.append(network)
    if run is not None:
        rows.insert(0, ("front end (read .. network input)", 0, run.front_end_seconds, None))
        rows.append(
            (f"whole frame ({MODES[run.overlap]} a3d-run)", network[1], run.frame_seconds, network[3])
        )
    for label, macs, seconds, at in rows:
        tail = f"{1e3 * at:15.1f}{at / seconds:11.0%} " if at is not None else f"{'-':>15s}{'-':>12s}"
        print(f"  {label:34s}{macs / 1e9:8.1f}{1e3 * seconds:9.1f}{tail}")
    if run is not None:
        rest = run.frame_seconds - run.stages["network"]
        at_ceiling = 1e3 * (network[3] + rest)
        print(f"  the frame at the ceiling: {at_ceiling:.0f} ms (network at the ceiling + the rest as "
              f"measured, {1e3 * rest:.0f} ms); measured {1e3 * run.frame_seconds:.0f} ms")  # fmt: skip


def print_head_ops(title: str, profile: NetworkProfile, c: Ceilings, top: int = 10) -> None:
    """Where the head's time goes, by operator type: share, MACs, GMAC/s and its ceiling."""
    head = [o for o in profile.ops if o.part == "head"]
    total = sum(o.seconds for o in head) or 1.0
    print(f"\n{title}: the head by operator ({profile.rois} RoIs, {1e3 * total:.1f} ms)")
    print(f"  {'op':24s}{'nodes':>6s}{'ms':>8s}{'share':>7s}{'GMAC':>7s}{'GMAC/s':>8s}{'ceiling':>9s}")
    for o in head[:top]:
        rate = f"{o.macs / o.seconds / 1e9:8.1f}" if o.macs and o.seconds else f"{'-':>8s}"
        ceiling = f"{o.ceiling(c) / 1e9:6.1f} {'i8' if o.int8 else 'f32'}" if o.macs else f"{'-':>9s}"
        print(
            f"  {o.op:24s}{o.nodes:6d}{1e3 * o.seconds:8.1f}{o.seconds / total:7.0%}"
            f"{o.macs / 1e9:7.2f}{rate}{ceiling}"
        )
    rest = head[top:]
    if rest:
        print(f"  {len(rest)} other op types{'':8s}{1e3 * sum(o.seconds for o in rest):8.1f}"
              f"{sum(o.seconds for o in rest) / total:7.0%}")  # fmt: skip


def print_export_choice(networks: dict[str, NetworkResult]) -> None:
    """Which export runs the network faster on this machine, measured, and the CPU-flag advice."""
    int8, fp32 = networks["ort int8 + SVD"].seconds, networks["ort fp32"].seconds
    faster = "int8 + SVD" if int8 < fp32 else "fp32"
    print(f"\nfaster export on this machine: {faster} (network alone: int8 + SVD {1e3 * int8:.0f} ms, "
          f"fp32 {1e3 * fp32:.0f} ms, {max(int8, fp32) / min(int8, fp32):.2f}x)")  # fmt: skip
    print(f"  a3d.runtime.network.cpu_support.export_advice(): {export_advice()}")


def print_targets(m: Measurements) -> None:
    """Ratios, then a PASS/FAIL line per target (the faster a3d-run mode of the full model)."""
    best = min(m.full, key=lambda r: r.frame_seconds)
    alone = m.networks["ort int8 + SVD"].seconds
    fp32 = m.networks["ort fp32"].seconds
    torch_fp32 = m.networks["torch eager fp32"].seconds if "torch eager fp32" in m.networks else None
    print("\nratios (machine independent)")
    print(
        f"  end to end ({MODES[best.overlap]}) / network alone, int8 + SVD: {best.frame_seconds / alone:.2f}"
    )
    print(f"  int8 + SVD / fp32, ONNX Runtime network: {alone / fp32:.2f}")
    if torch_fp32 is not None:
        print(f"  ONNX Runtime fp32 / torch eager fp32 network: {fp32 / torch_fp32:.2f}")
    print(f"\ntargets ({load_average()} now)")
    profile, c = m.profiles.get("int8 + SVD"), m.ceilings
    if profile is not None:
        reached = profile.seconds_at_ceiling("trunks", c) / profile.seconds("trunks")
        _target(f"int8 trunks >= {TARGET_TRUNKS_OF_CEILING:.0%} of the measured int8 convolution ceiling",
                reached >= TARGET_TRUNKS_OF_CEILING, f"{reached:.0%}")  # fmt: skip
        pooling = profile.pooling_seconds()
        rounds = ", ".join(f"{1e3 * p.pooling_seconds():.1f}" for p in m.int8_profiles)
        _target(f"RoI pooling <= {1e3 * TARGET_POOLING_SECONDS:.0f} ms at {profile.rois} RoIs (int8 + SVD "
                "head less its fully connected layers)", pooling <= TARGET_POOLING_SECONDS,
                f"{1e3 * pooling:.1f} ms (the fastest profile's; each round's: {rounds} ms)")  # fmt: skip
    mode = MODES[best.overlap]
    _target(f"int8 + SVD end to end <= {TARGET_E2E_OVER_NETWORK} x its network alone",
            best.frame_seconds <= TARGET_E2E_OVER_NETWORK * alone,
            f"{best.frame_seconds:.3f} s vs {TARGET_E2E_OVER_NETWORK} x {alone:.3f} s ({mode})")  # fmt: skip
    if cpu_flags() & set(INT8_DOT_PRODUCT):
        _target(f"int8 + SVD end to end <= {PAPER_SECONDS} s (the paper: Titan X, network only)",
                best.frame_seconds <= PAPER_SECONDS,
                f"{best.frame_seconds:.3f} s a frame ({mode})")  # fmt: skip
    elif profile is not None:
        projected = profile.seconds_at_ceiling("trunks", c) + profile.seconds_at_ceiling("head", c)
        projected += best.frame_seconds - best.stages["network"]
        print(f"  [n/a ] int8 + SVD end to end <= {PAPER_SECONDS} s needs int8 dot products (no VNNI here): "
              f"measured {best.frame_seconds:.3f} s ({mode}), {projected:.3f} s projected at this "
              "machine's ceilings")  # fmt: skip
    for name, runs in (("full model", m.full), ("small model", m.small)):
        modes = {r.overlap: r for r in runs}
        if "auto" in modes and "off" in modes:
            auto, seq = modes["auto"].frame_seconds, modes["off"].frame_seconds
            _target(f"--overlap auto never slower than sequential, {name} (within {OVERLAP_NOISE - 1:.0%})",
                    auto <= OVERLAP_NOISE * seq, f"{1e3 * auto:.0f} ms vs {1e3 * seq:.0f} ms, "
                    f"{modes['auto'].overlapped} frames overlapped")  # fmt: skip
    if torch_fp32 is not None:
        speedup = torch_fp32 / fp32
        _target(f"ONNX Runtime fp32 >= {TARGET_ORT_OVER_TORCH} x faster than torch eager fp32",
                speedup >= TARGET_ORT_OVER_TORCH, f"{speedup:.2f} x")  # fmt: skip
    peak = max(r.peak_bytes for r in m.full)
    _target("peak resident memory of a3d-run with the int8 model <= 2 GiB", peak <= TARGET_PEAK_BYTES,
            f"{peak / 2**30:.2f} GiB")  # fmt: skip


def _target(what: str, ok: bool, detail: str) -> None:
    print(f"  [{'PASS' if ok else 'FAIL'}] {what}: {detail}")
