"""Horizontal layers of random tilt-frame points (y down), for floor and cluster tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def point_layer(
    rng: np.random.Generator, n: int, y: float | Callable[[np.ndarray, np.ndarray], np.ndarray],
    x: tuple[float, float], z: tuple[float, float],
) -> np.ndarray:  # fmt: skip
    """(n, 3) points spread uniformly over ``x`` and ``z`` at height ``y`` (a number or y(x, z))."""
    xs, zs = rng.uniform(*x, n), rng.uniform(*z, n)
    return np.column_stack([xs, y(xs, zs) if callable(y) else np.full(n, y), zs])
