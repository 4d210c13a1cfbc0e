"""Fitting a training run to a wall-clock budget (``solver.minutes``, ``a3d-train --minutes``).

CPUs differ from machine to machine (bfloat16 on AMX trains twice as fast as on AVX2, and two
hosts of the same kind differ by a tenth or more), so "train for an hour" cannot be written as an
iteration count. With ``solver.minutes`` > 0, a3d-train times iterations ``WARMUP`` to
``PLAN_AFTER`` of its run and fits the run's length to the time left at that rate:
``solver.iterations`` is the ceiling, and ``solver.lr_steps`` (given for the ceiling) are scaled in
proportion, so the schedule keeps its shape. From then on the run is an ordinary one of the fitted
length: config.json and every later checkpoint hold the fitted schedule (with ``minutes`` 0), so
``--resume`` continues it unchanged. The clock starts when the run starts building its RoI database
(the proposals of uncached frames count; on ``--resume`` it starts at the resume); the end-of-run
validation (``--val``) is outside it.
"""

from __future__ import annotations

from dataclasses import replace

from a3d.train.config import SolverConfig

WARMUP = 20  # iterations not timed (first allocations, data loader start)
PLAN_AFTER = 200  # the iteration (after the run's start) at which the length is fitted
END_SECONDS = 15.0  # kept for the last checkpoint and loss plot


def fit_schedule(solver: SolverConfig, done: int, rate: float, seconds_left: float) -> SolverConfig:
    """``solver`` with ``iterations`` fitted to ``seconds_left`` at ``rate`` iterations per second
    after ``done`` iterations (at most the ceiling ``solver.iterations``, at least ``done``), its
    ``lr_steps`` scaled by the same factor, and ``minutes`` 0 (the plan is made)."""
    if rate <= 0:
        raise ValueError(f"solver.minutes: measured rate {rate} iterations/s is not positive")
    fitted = done + max(0, int(rate * seconds_left))
    fitted = min(solver.iterations, fitted)
    scale = fitted / solver.iterations
    steps = tuple(round(step * scale) for step in solver.lr_steps)
    return replace(solver, iterations=fitted, lr_steps=steps, minutes=0.0)
