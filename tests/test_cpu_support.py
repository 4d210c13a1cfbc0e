"""a3d.runtime.network.cpu_support: the int8 / fp32 advice from the CPU's flags."""

from __future__ import annotations

import pytest

from a3d.runtime.network.cpu_support import bf16_instructions, cpu_flags, export_advice

X86 = """processor\t: 0
vendor_id\t: AuthenticAMD
flags\t\t: fpu sse sse2 avx fma avx2 sha_ni
processor\t: 1
flags\t\t: fpu sse sse2 avx fma avx2 sha_ni avx512f avx512_vnni
"""
ARM = """processor\t: 0
BogoMIPS\t: 50.00
Features\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm asimddp
"""


def test_flags_are_the_first_cpus() -> None:
    assert cpu_flags(X86) == {"fpu", "sse", "sse2", "avx", "fma", "avx2", "sha_ni"}
    assert "asimddp" in cpu_flags(ARM)
    assert cpu_flags("processor : 0\n") == frozenset()


@pytest.mark.parametrize(
    ("flags", "export", "says"),
    [
        ({"avx2", "avx512f", "avx512_vnni"}, "int8", "avx512_vnni"),
        ({"avx2", "avx_vnni"}, "int8", "avx_vnni"),
        ({"avx2", "amx_int8", "avx512_vnni"}, "int8", "avx512_vnni, amx_int8"),
        ({"asimd", "asimddp"}, "int8", "asimddp"),
        ({"avx", "avx2", "fma"}, "int8", "AVX2 without VNNI"),
        ({"sse4_2", "avx"}, "fp32", "no AVX2"),
        ({"asimd"}, "fp32", "no AVX2"),
        (set(), "fp32", "unknown"),
    ],
)
def test_advice_follows_the_int8_instructions(flags: set[str], export: str, says: str) -> None:
    advice = export_advice(frozenset(flags))
    assert advice.export == export
    assert says in advice.reason and str(advice).startswith(f"{export}: ")


def test_advice_reads_this_machine_by_default() -> None:
    assert export_advice() == export_advice(cpu_flags())


@pytest.mark.parametrize(
    ("flags", "native"),
    [
        ({"avx2", "avx512f", "avx512_bf16", "amx_bf16", "amx_int8"}, ["amx_bf16", "avx512_bf16"]),
        ({"avx2", "avx512f", "avx512_vnni"}, []),  # AVX-512 without BF16: PyTorch emulates bfloat16
        ({"asimd", "asimddp", "bf16"}, ["bf16"]),
        (set(), []),
    ],
)
def test_bf16_instructions_are_the_native_ones(flags: set[str], native: list[str]) -> None:
    assert bf16_instructions(frozenset(flags)) == native
