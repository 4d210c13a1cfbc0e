"""bench.machine_speed: slow calls grouped into spells (the machine's two speeds)."""

from pathlib import Path

import numpy as np
import pytest

from bench.machine_speed import Spell, main, speed_spells

REPO = Path(__file__).resolve().parents[1]


def test_slow_calls_form_spells_with_their_start_and_length() -> None:
    seconds = np.array([0.45, 0.46, 0.52, 0.53, 0.45, 0.45, 0.55, 0.56])
    starts = np.concatenate([[10.0], 10.0 + np.cumsum(seconds[:-1])])  # back to back, from t = 10 s
    summary = speed_spells(starts, seconds, window=1)
    assert summary.fast_median == pytest.approx(0.45)
    assert summary.slow_median == pytest.approx(0.54)
    assert summary.slow_share == pytest.approx(0.5)
    assert summary.spells == [
        Spell(start=pytest.approx(0.91), seconds=pytest.approx(1.05), calls=2),
        Spell(start=pytest.approx(2.86), seconds=pytest.approx(1.11), calls=2),  # open at the end
    ]


def test_one_late_call_is_no_spell_but_a_run_of_them_is() -> None:
    seconds = np.array([0.3, 0.3, 0.4, 0.3, 0.3, 0.3, 0.4, 0.4, 0.4, 0.4, 0.3, 0.3])
    summary = speed_spells(np.arange(12.0), seconds, window=3)
    assert [(s.start, s.calls) for s in summary.spells] == [(6.0, 4)]
    assert summary.slow_share == pytest.approx(4 / 12)


def test_the_fastest_call_is_fast_even_amid_slow_ones() -> None:
    summary = speed_spells(np.arange(5.0), np.array([0.5, 0.5, 0.4, 0.5, 0.5]), window=5)
    assert summary.fast_median == pytest.approx(0.4) and summary.slow_share == pytest.approx(0.8)
    assert [(s.start, s.calls) for s in summary.spells] == [(0.0, 2), (3.0, 2)]


def test_one_speed_has_no_spell_and_mismatched_lengths_are_refused() -> None:
    summary = speed_spells(np.arange(5.0), np.full(5, 0.3) + 0.005 * np.arange(5))  # within 8 %
    assert summary.slow_median is None and summary.spells == [] and summary.slow_share == 0
    with pytest.raises(ValueError, match="as many call starts as call times"):
        speed_spells(np.arange(3.0), np.ones(2))


def test_the_command_times_the_bundled_model(capsys: pytest.CaptureFixture) -> None:
    assert main([str(REPO / "runtime/models/live.onnx"), str(REPO / "samples"), "--seconds", "1",
                 "--threads", "1", "--max-proposals", "50"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    calls = int(out.split("\n")[1].split()[0])
    assert calls >= 2 and "fastest" in out
