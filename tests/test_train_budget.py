"""a3d-train --minutes: the run's length fitted to a wall-clock budget at its measured rate, the
lr steps scaled alike, and the fitted schedule written where --resume reads it."""

from __future__ import annotations

import itertools
import json
import logging
import time

import pytest

from a3d.train import loop
from a3d.train.budget import fit_schedule
from a3d.train.checkpoint import checkpoint_config
from a3d.train.cli import main
from a3d.train.config import SolverConfig
from a3d.train.loop import read_metrics
from tests.helpers.train_scenes import tiny_train_args, write_scenes


def test_fit_schedule_scales_length_and_steps():
    solver = SolverConfig(iterations=10000, lr_steps=(8000, 9500), minutes=60.0)
    fitted = fit_schedule(solver, done=200, rate=2.5, seconds_left=3000.0)
    assert fitted.iterations == 200 + 7500
    assert fitted.lr_steps == (round(8000 * 0.77), round(9500 * 0.77))  # the same fractions of the run
    assert fitted.minutes == 0.0 and solver.minutes == 60.0  # the plan is made; the input is untouched


def test_fit_schedule_keeps_the_ceiling_and_what_is_done():
    solver = SolverConfig(iterations=1000, lr_steps=(800,), minutes=60.0)
    assert fit_schedule(solver, 200, rate=50.0, seconds_left=3000.0).iterations == 1000  # ends early
    assert fit_schedule(solver, 200, rate=50.0, seconds_left=3000.0).lr_steps == (800,)
    spent = fit_schedule(solver, 200, rate=2.0, seconds_left=-30.0)  # the budget went on proposals
    assert spent.iterations == 200
    with pytest.raises(ValueError, match="rate"):
        fit_schedule(solver, 200, rate=0.0, seconds_left=10.0)


def test_a_refit_keeps_the_steps_already_passed():
    budget = SolverConfig(iterations=10000, lr_steps=(5000, 9000), minutes=60.0)
    first = fit_schedule(budget, 200, rate=2.0, seconds_left=3900.0)  # 8000 iterations, steps 4000, 7200
    assert (first.iterations, first.lr_steps) == (8000, (4000, 7200))
    # at 5000 the host turns out slower: the run shrinks, the passed step stays, the next one
    # scales, and one that would land in the past lands now (not before: lr never goes back up)
    slower = fit_schedule(budget, 5000, rate=1.0, seconds_left=1000.0, current=first)
    assert (slower.iterations, slower.lr_steps) == (6000, (4000, 5400))
    slowest = fit_schedule(budget, 5000, rate=1.0, seconds_left=100.0, current=first)
    assert (slowest.iterations, slowest.lr_steps) == (5100, (4000, 5000))


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return write_scenes(tmp_path_factory.mktemp("budget") / "frames", 2, seed=3)


def test_a_run_fits_its_minutes(frames, tmp_path, monkeypatch):
    monkeypatch.setattr(loop, "WARMUP", 2)
    monkeypatch.setattr(loop, "PLAN_AFTER", 6)
    monkeypatch.setattr(loop, "REFIT_EVERY", 25)
    monkeypatch.setattr(loop, "END_SECONDS", 0.0)
    budget_s = 6.0
    run = tmp_path / "run"
    args = tiny_train_args(frames, run, tmp_path / "cache", "solver.lr_steps=[30000]",
                           "log.checkpoint_every=100000")  # fmt: skip
    start = time.monotonic()
    assert main([*args, "--iters", "100000", "--minutes", str(budget_s / 60)]) == 0
    elapsed = time.monotonic() - start
    records = read_metrics(run / "metrics.jsonl")
    plans = [r for r in records if r["kind"] == "plan"]
    assert [r["iter"] for r in plans] == list(range(6, plans[-1]["iter"] + 1, 25)) and len(plans) > 1
    plan = plans[-1]  # the last fit is the run's schedule
    fitted = plan["iterations"]
    # a refit may find the budget spent and end the run where it stands, so the last plan can end at
    # its own iteration; the first one, made with most of the budget left, plans ahead
    assert plan["ceiling"] == 100000 and plan["iter"] <= fitted < 100000
    assert plans[0]["iter"] < plans[0]["iterations"]
    train = [r for r in records if r["kind"] == "train"]
    assert train[-1]["iter"] == fitted  # it stopped there
    assert plans[0]["lr_steps"] == [round(30000 * plans[0]["iterations"] / 100000)]
    for before, r in itertools.pairwise(plans):  # 30 % of each fitted length, until a fit passed it
        (old,), (step,) = before["lr_steps"], r["lr_steps"]
        scaled = max(r["iter"], round(30000 * r["iterations"] / 100000))
        assert step == (old if old <= r["iter"] else scaled)
    lrs = [r["lr"] for r in train]
    assert lrs == sorted(lrs, reverse=True) and lrs[-1] < lrs[0]  # one cut, never undone by a refit
    assert elapsed < 3 * budget_s, elapsed  # the rate of 4 iterations predicts the rest to within 3x
    # config.json and the checkpoint hold the fitted schedule, so --resume continues it as is
    for solver in (json.loads((run / "config.json").read_text())["solver"],
                   checkpoint_config(run / "checkpoint.pt").solver.__dict__):  # fmt: skip
        assert solver["iterations"] == fitted and solver["minutes"] == 0
        assert list(solver["lr_steps"]) == plan["lr_steps"]


def test_a_run_too_short_to_time_runs_its_iterations(frames, tmp_path, caplog):
    run = tmp_path / "run"
    with caplog.at_level(logging.INFO, logger=loop.__name__):
        args = [*tiny_train_args(frames, run, tmp_path / "cache"), "--iters", "3", "--minutes", "5"]
        assert main(args) == 0
    assert "too few to time" in caplog.text
    assert [r["iter"] for r in read_metrics(run / "metrics.jsonl") if r["kind"] == "train"][-1] == 3


BAD = [
    (["--minutes", "0"], "--minutes must be positive, got 0.0"),
    (["--set", "solver.minutes=-1"], "solver.minutes=-1"),
]


@pytest.mark.parametrize(("args", "message"), BAD)
def test_a_bad_budget_is_one_line(frames, tmp_path, capsys, args, message):
    run = tmp_path / "run"
    assert main([*tiny_train_args(frames, run, tmp_path / "cache"), *args]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and len(error.splitlines()) == 1, error
    assert not (run / "checkpoint.pt").exists()


def test_scaled_lr_steps_are_exact_not_float_rounded() -> None:
    """30000 of 100000 scaled to 395 iterations is exactly 118.5, which rounds to 118 (half to even);
    scaling by the float 395 / 100000 first gave 118.50000000000001 and so 119."""
    budget = SolverConfig(iterations=100000, lr_steps=(30000,))
    fitted = fit_schedule(budget, done=0, rate=39.5, seconds_left=10.0)
    assert fitted.iterations == 395 and fitted.lr_steps == (118,)
