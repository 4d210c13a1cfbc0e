"""Data-parallel training under ``torchrun``: process group, DDP wrapping, rank bookkeeping.

``torchrun --nproc_per_node N -m a3d.train.cli ...`` (or the ``a3d-train`` script) sets
``RANK``/``WORLD_SIZE``/``LOCAL_RANK``; without them training runs as a single process. The
backend is gloo on CPU and NCCL on CUDA (one GPU per local rank). Ranks draw different images
(``a3d.train.sampler``), DDP averages the gradients, and rank 0 alone writes checkpoints, logs
and plots. Every checkpoint first checks that all ranks still hold the same weights.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel


@dataclass(frozen=True)
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def init_distributed(device: torch.device) -> DistInfo:
    """Join the process group torchrun describes in the environment (a no-op for one process)."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return DistInfo()
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    if device.type == "cuda":
        torch.cuda.set_device(local_rank)
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.type == "cuda" else "gloo")
    return DistInfo(rank, world_size, local_rank)


def local_device(device: torch.device, info: DistInfo) -> torch.device:
    """The device this rank computes on (its own GPU under CUDA)."""
    if device.type == "cuda" and info.enabled:
        return torch.device("cuda", info.local_rank)
    return device


def wrap_model(model: torch.nn.Module, info: DistInfo) -> torch.nn.Module:
    """DDP around the model when more than one process trains (BatchNorm buffers follow rank 0)."""
    if not info.enabled:
        return model
    device_ids = [info.local_rank] if next(model.parameters()).is_cuda else None
    return DistributedDataParallel(model, device_ids=device_ids)


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    return model.module if isinstance(model, DistributedDataParallel) else model


def mean_over_ranks(values: dict[str, float], info: DistInfo, device: torch.device) -> dict[str, float]:
    """Average scalar metrics over ranks (identity for one process)."""
    if not info.enabled or not values:
        return values
    keys = sorted(values)
    t = torch.tensor([values[k] for k in keys], dtype=torch.float64, device=device)
    dist.all_reduce(t)
    return {k: float(v) / info.world_size for k, v in zip(keys, t.tolist(), strict=True)}


def parameter_digest(model: torch.nn.Module) -> torch.Tensor:
    """(2,) float64 fingerprint of the parameters: their sum and a position-weighted sum.

    Buffers are left out: BatchNorm running statistics are updated from each rank's own batch
    and re-broadcast from rank 0 at the next forward, so they legitimately differ in between.
    """
    flat = torch.cat([p.detach().reshape(-1).double() for p in unwrap(model).parameters()])
    weights = torch.arange(flat.numel(), device=flat.device, dtype=torch.float64).remainder_(97).add_(1)
    return torch.stack([flat.sum(), (flat * weights).sum()])


def rank_digests(model: torch.nn.Module, info: DistInfo) -> list[list[float]]:
    """Every rank's parameter digest (collective: all ranks must call it)."""
    digest = parameter_digest(model)
    if not info.enabled:
        return [digest.tolist()]
    gathered = [torch.empty_like(digest) for _ in range(info.world_size)]
    dist.all_gather(gathered, digest)
    return [g.tolist() for g in gathered]


def check_in_sync(model: torch.nn.Module, info: DistInfo) -> list[list[float]]:
    """Raise if any rank's weights differ from rank 0's; returns the digests (collective)."""
    digests = rank_digests(model, info)
    if any(d != digests[0] for d in digests[1:]):
        raise RuntimeError(f"DDP ranks out of sync: parameter digests {digests}")
    return digests


def barrier(info: DistInfo) -> None:
    if info.enabled:
        dist.barrier()


def shutdown(info: DistInfo) -> None:
    if info.enabled and dist.is_initialized():
        dist.destroy_process_group()
