"""Which export to run on this CPU, int8 or fp32, from the instruction set it reports.

ONNX Runtime's int8 kernels (uint8 activations x int8 weights, what ``a3d-export --int8``
writes) are fast where the CPU has int8 dot-product instructions: x86 AVX-512 VNNI, AVX-VNNI or
AMX, ARM's dot product (asimddp) or i8mm; there the int8 + SVD model runs the network about
3-4x faster than fp32. With AVX2 alone int8 still gains, far less (1.5-2x on the GEMM and
convolution ceilings ``python -m bench.edge_speed`` measured on an AVX2-only AMD EPYC); without
AVX2 or a dot product int8 gains nothing worth its accuracy cost. ``python -m bench.edge_speed``
measures both exports on the machine itself; this is the quick answer without a benchmark.

    from a3d.runtime.network.cpu_support import export_advice
    print(export_advice())
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

INT8_DOT_PRODUCT = ("avx512_vnni", "avx_vnni", "amx_int8", "asimddp", "i8mm")
BF16_NATIVE = ("amx_bf16", "avx512_bf16", "bf16")  # x86 AMX / AVX-512 BF16, ARM's BF16 extension


@dataclass(frozen=True)
class ExportAdvice:
    """The export that should run faster here (``export``) and why, in one line (``reason``)."""

    export: Literal["int8", "fp32"]
    reason: str

    def __str__(self) -> str:
        return f"{self.export}: {self.reason}"


def cpu_flags(cpuinfo: str | None = None) -> frozenset[str]:
    """The first CPU's instruction-set flags from ``/proc/cpuinfo`` (x86 ``flags``, ARM
    ``Features``), or from ``cpuinfo``'s text; empty where there is no such file (not Linux)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return frozenset()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return frozenset(value.split())
    return frozenset()


def int8_dot_products(flags: frozenset[str] | None = None) -> list[str]:
    """The int8 dot-product instructions among ``flags`` (default: this machine's). Where there is
    one, ONNX Runtime's int8 kernels add exactly; AVX2's uint8 x int8 kernel saturates an
    intermediate 16-bit sum, so the runtime asks for its exact, slower uint8 x uint8 one there
    (a3d.runtime.network.model.session_options)."""
    return _among(INT8_DOT_PRODUCT, flags)


def bf16_instructions(flags: frozenset[str] | None = None) -> list[str]:
    """The native bfloat16 instructions among ``flags`` (default: this machine's): where there is
    none, PyTorch emulates bfloat16 and a3d-train's ``solver.precision=bf16`` runs slower, not faster."""
    return _among(BF16_NATIVE, flags)


def _among(names: tuple[str, ...], flags: frozenset[str] | None) -> list[str]:
    """``names`` that are in ``flags`` (default: this machine's, ``cpu_flags``), in ``names``' order."""
    flags = cpu_flags() if flags is None else flags
    return [name for name in names if name in flags]


def export_advice(flags: frozenset[str] | None = None) -> ExportAdvice:
    """int8 where the CPU has an int8 dot product or AVX2, fp32 otherwise (module docstring);
    ``flags`` default to this machine's (``cpu_flags``)."""
    flags = cpu_flags() if flags is None else flags
    dot = int8_dot_products(flags)
    if dot:
        return ExportAdvice(
            "int8", f"int8 dot products ({', '.join(dot)}): int8 + SVD about 3-4x faster than fp32"
        )
    if "avx2" in flags:
        return ExportAdvice(
            "int8", "AVX2 without VNNI: int8 + SVD still faster than fp32, by about 1.5-2x instead of 3-4x"
        )
    if not flags:
        return ExportAdvice("fp32", "instruction set unknown (no /proc/cpuinfo): fp32, the safe choice")
    return ExportAdvice("fp32", "no AVX2 and no int8 dot product: int8 gains little over fp32 here")
