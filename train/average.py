"""Weight averaging of fine-tuned runs ("model soup", Wortsman et al. 2022).

Runs fine-tuned from one checkpoint (``a3d-train --set solver.init=...``) with other seeds or other
scenes stay in one basin of the loss; the mean of their weights is one network of the same cost
that is usually better than each of them. Averaging only makes sense for such runs: they must share
the network config and the regression targets (delta statistics, class mean sizes) that
``solver.init`` carries over, and that is checked here. Batch norm's running statistics are
averaged like the weights; integer buffers (batch counters) take the largest.

The result is a checkpoint without optimizer state: ``a3d-export`` and ``solver.init`` take it,
``--resume`` does not. It keeps the first run's config and names its sources (path, sha256,
iteration) under ``averaged``, which a3d-export copies into the model's provenance.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import torch

from a3d.train.checkpoint import CheckpointError, checkpoint_config, file_sha256, load_trained_state

CARRIED = ("config", "target_stats", "mean_sizes", "classes")


def average_checkpoints(paths: Sequence[str | os.PathLike]) -> dict:
    """The checkpoint payload whose weights are the mean of ``paths``' (two or more runs fine-tuned
    from one checkpoint); CheckpointError "PATH: why" for one that does not fit the first."""
    if len(paths) < 2:
        raise ValueError(f"averaging needs two or more checkpoints, got {len(paths)}")
    paths = [Path(p) for p in paths]
    states = [load_trained_state(p) for p in paths]
    for path, state in zip(paths[1:], states[1:], strict=True):
        _check_fits(path, state, paths[0], states[0])
    model = {}
    for name, value in states[0]["model"].items():
        values = [state["model"][name] for state in states]
        if value.is_floating_point():
            model[name] = torch.stack([v.double() for v in values]).mean(0).to(value.dtype)
        else:
            model[name] = torch.stack(values).amax(0)
    sources = [{"path": str(p.resolve()), "sha256": file_sha256(p), "iteration": int(s["iteration"])}
               for p, s in zip(paths, states, strict=True)]  # fmt: skip
    carried = {key: states[0][key] for key in CARRIED if key in states[0]}
    return {"iteration": max(s["iteration"] for s in sources), **carried, "model": model, "averaged": sources}


def _check_fits(path: Path, state: dict, first_path: Path, first: dict) -> None:
    """The same network, weight for weight, trained for the same regression targets: heads trained
    for other targets cannot be averaged, their deltas mean other boxes."""
    if checkpoint_config(path, state).net != checkpoint_config(first_path, first).net:
        raise CheckpointError(f"{path}: another network config than {first_path}")
    shapes = {name: tuple(v.shape) for name, v in state["model"].items()}
    if shapes != {name: tuple(v.shape) for name, v in first["model"].items()}:
        raise CheckpointError(f"{path}: other weights (names or shapes) than {first_path}")
    targets = [(state["mean_sizes"], first["mean_sizes"])]
    targets += [(state["target_stats"].get(k), v) for k, v in first["target_stats"].items()]
    if any(a is None or not torch.equal(torch.as_tensor(a), torch.as_tensor(b)) for a, b in targets):
        raise CheckpointError(
            f"{path}: other regression targets (delta statistics or mean sizes) than {first_path}; "
            "average only runs fine-tuned from one checkpoint (solver.init)"
        )
