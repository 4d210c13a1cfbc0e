"""Fitting a training run to a wall-clock budget (``solver.minutes``, ``a3d-train --minutes``).

CPUs differ from machine to machine (bfloat16 on AMX trains twice as fast as on AVX2, and two
hosts of the same kind differ by a tenth), so "train for an hour" cannot be written as an
iteration count. With ``solver.minutes`` > 0, a3d-train times its iterations from ``WARMUP`` on
and, at ``PLAN_AFTER`` and every ``REFIT_EVERY`` iterations after, fits the run's length to the
time left at the rate so far: ``solver.iterations`` is the ceiling, and ``solver.lr_steps`` (given
for the ceiling) scale in proportion, so the schedule keeps its shape; a step already passed stays
where it was. config.json and the checkpoints hold the latest fitted schedule as an ordinary one
(``minutes`` 0), so ``--resume`` continues it without fitting again. The clock starts when the run
starts building its RoI database (the proposals of uncached frames count; on ``--resume`` it
starts at the resume); the end-of-run validation (``--val``) is outside it.
"""

from __future__ import annotations

from dataclasses import replace

from a3d.train.config import SolverConfig

WARMUP = 20  # iterations not timed (first allocations, data loader start)
PLAN_AFTER = 200  # the iteration (after the run's start) of the first fit
REFIT_EVERY = 500  # iterations between later fits (a host's speed drifts)
END_SECONDS = 15.0  # kept for the last checkpoint and loss plot


def fit_schedule(
    budget: SolverConfig, done: int, rate: float, seconds_left: float, current: SolverConfig | None = None
) -> SolverConfig:
    """``budget`` with ``iterations`` fitted to ``seconds_left`` at ``rate`` iterations per second
    after ``done`` iterations (at most the ceiling ``budget.iterations``, at least ``done``), its
    ``lr_steps`` scaled by the same factor (those of ``current``, an earlier fit, that are passed
    stay put; none lands before ``done``) and ``minutes`` 0."""
    if rate <= 0:
        raise ValueError(f"solver.minutes: measured rate {rate} iterations/s is not positive")
    fitted = min(budget.iterations, done + max(0, int(rate * seconds_left)))
    earlier = current.lr_steps if current is not None else (None,) * len(budget.lr_steps)
    steps = tuple(
        old if old is not None and old <= done else max(done, round(step * fitted / budget.iterations))
        for step, old in zip(budget.lr_steps, earlier, strict=True)
    )
    return replace(budget, iterations=fitted, lr_steps=steps, minutes=0.0)
