"""Multi-process data parallel training (``torchrun``).

``torchrun --nproc_per_node=K -m rdnet.train.run ...`` starts K processes with the
``RANK``/``WORLD_SIZE``/``LOCAL_RANK``/``MASTER_*`` variables set; :func:`init_from_env`
joins them into one process group (``nccl`` on CUDA, ``gloo`` on CPU) and
:func:`rdnet.train.loop.train` wraps the network in ``DistributedDataParallel``.

Sharding: every global step's batch (``train.batch_size`` rows, a pure function of
``(seed, step)``) is split into K equal contiguous slices, one per rank
(:class:`rdnet.train.data.StepSampler`); DDP averages the gradients, so a step
optimises the same batch mean as a single process (up to float summation order) for
losses that are plain means (L_d); the masked restoration loss is normalised by each
shard's mask count, so there DDP optimises the mean of the shards' losses. Only
rank 0 logs and writes checkpoints; :func:`replica_digests` records a hash of every
rank's weights in each checkpoint to show that the replicas stayed identical.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn


@dataclass(frozen=True)
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0


def is_distributed() -> bool:
    return dist.is_available() and dist.is_initialized()


def dist_info() -> DistInfo:
    """This process's rank / world size (0 / 1 when not distributed)."""
    if not is_distributed():
        return DistInfo()
    return DistInfo(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", 0)))


def init_from_env(device: str = "auto") -> DistInfo:
    """Join the process group described by torchrun's environment variables, when
    ``WORLD_SIZE`` > 1 (no-op otherwise). ``device`` (train.device) picks the backend:
    nccl when it resolves to CUDA, else gloo."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1 or is_distributed():
        return dist_info()
    use_cuda = device == "cuda" or (device == "auto" and torch.cuda.is_available())
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if use_cuda:
        torch.cuda.set_device(local)
    dist.init_process_group(backend="nccl" if use_cuda else "gloo")
    return dist_info()


def cleanup() -> None:
    if is_distributed():
        dist.destroy_process_group()


def _device_for_collectives() -> torch.device:
    if is_distributed() and dist.get_backend() == "nccl":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device("cpu")


def all_reduce_mean(value: torch.Tensor) -> torch.Tensor:
    """Mean of a scalar tensor over ranks (the tensor itself when not distributed)."""
    if not is_distributed():
        return value.detach()
    t = value.detach().to(_device_for_collectives(), torch.float64).clone()
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return t / dist.get_world_size()


def barrier() -> None:
    if is_distributed():
        if dist.get_backend() == "nccl":
            dist.barrier(device_ids=[torch.cuda.current_device()])
        else:
            dist.barrier()


def weights_digest(net: nn.Module) -> str:
    """SHA-256 of the network's state (names, dtypes, shapes and bytes)."""
    h = hashlib.sha256()
    for k, v in net.state_dict().items():
        a = v.detach().cpu().contiguous()
        h.update(f"{k}:{a.dtype}:{tuple(a.shape)}".encode())
        h.update(a.reshape(-1).view(torch.uint8).numpy().tobytes() if a.numel() else b"")
    return h.hexdigest()


def replica_digests(net: nn.Module) -> list[str]:
    """:func:`weights_digest` of every rank (a collective: all ranks must call it)."""
    d = weights_digest(net)
    if not is_distributed():
        return [d]
    raw = torch.frombuffer(bytearray(bytes.fromhex(d)), dtype=torch.int64).clone()
    out = [torch.zeros_like(raw) for _ in range(dist.get_world_size())]
    dev = _device_for_collectives()
    out = [o.to(dev) for o in out]
    dist.all_gather(out, raw.to(dev))
    return [o.cpu().numpy().tobytes().hex() for o in out]
