"""Running the trainer on one process or under torchrun (DDP: gloo on CPU, nccl on GPU).

Also owns which samples each rank sees: `StepBatchSampler` gives every rank a
disjoint, deterministic slice of a per-epoch permutation, addressed by global
step, so a resumed run reads exactly the batches it would have read; and a
run's CPU thread budget (`torch_threads`).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass

import torch
import torch.distributed as dist
import torch.nn as nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import Sampler

from htdata.errors import ConfigError


def _busy_seconds() -> float | None:
    """CPU seconds the whole machine has spent busy since boot (/proc/stat), None where unreadable."""
    try:
        fields = [float(x) for x in open("/proc/stat").readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)      # idle + iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def free_cores(sample_s: float = 0.3) -> int:
    """The cores this process may use (its CPU affinity) less those other processes keep busy, measured
    over `sample_s` (machine busy time less this process's own), at least 1: the thread count that does
    not fight other jobs for cores. More threads than free cores multiplied a phase's time (docs/
    HANDTOUCH.md, "How long it takes"). Where /proc/stat is missing: the 1-minute load average."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    before, mine = _busy_seconds(), sum(os.times()[:2])
    if before is None:
        others = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    else:
        time.sleep(sample_s)
        others = max((_busy_seconds() - before) - (sum(os.times()[:2]) - mine), 0.0) / sample_s
    return max(1, min(cores, int(cores - others + 0.5)))


@contextlib.contextmanager
def torch_threads(n: int | None):
    """torch's intra-op thread count set to n inside the block (None / 0: unchanged), restored after."""
    before = torch.get_num_threads()
    if n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@dataclass(frozen=True)
class DistEnv:
    rank: int
    world_size: int
    local_rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def resolve_device(spec: str, local_rank: int = 0) -> torch.device:
    """'auto' -> CUDA (this process's local rank) when available, else CPU."""
    if spec == "auto":
        spec = "cuda" if torch.cuda.is_available() else "cpu"
    if spec.startswith("cuda"):
        if not torch.cuda.is_available():
            raise RuntimeError(f"device {spec!r} requested but CUDA is not available")
        return torch.device(spec if ":" in spec else f"cuda:{local_rank}")
    return torch.device(spec)


def init_distributed(device_spec: str = "auto") -> DistEnv:
    """Join the process group when launched by torchrun (WORLD_SIZE > 1), else single process."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    device = resolve_device(device_spec, local_rank)
    if world > 1 and not dist.is_initialized():
        backend = "nccl" if device.type == "cuda" else "gloo"
        if device.type == "cuda":
            torch.cuda.set_device(device)
        dist.init_process_group(backend=backend, rank=rank, world_size=world)
    return DistEnv(rank, world, local_rank, device)


def shutdown(env: DistEnv) -> None:
    if env.distributed and dist.is_initialized():
        dist.destroy_process_group()


def barrier(env: DistEnv) -> None:
    if env.distributed:
        dist.barrier()


def wrap(model: nn.Module, env: DistEnv) -> nn.Module:
    """DDP wrapper for a multi-process run (build it after the stage's freezing)."""
    if not env.distributed:
        return model
    ids = [env.device.index] if env.device.type == "cuda" else None
    return DistributedDataParallel(model, device_ids=ids)


def unwrap(model: nn.Module) -> nn.Module:
    return model.module if isinstance(model, DistributedDataParallel) else model


def mean_across_ranks(values: dict[str, float], env: DistEnv) -> dict[str, float]:
    if not env.distributed or not values:
        return values
    keys = sorted(values)
    t = torch.tensor([values[k] for k in keys], dtype=torch.float64)
    dist.all_reduce(t)
    return {k: float(v) / env.world_size for k, v in zip(keys, t)}


class StepBatchSampler(Sampler[list[int]]):
    """Batches for global steps [start_step, stop_step) of one rank.

    Epoch e is a permutation of range(n) seeded by (seed, e); each step takes the next
    batch_size * world_size indices and this rank keeps its own batch_size of them.
    The tail of an epoch shorter than a global batch is dropped, so ranks stay balanced.
    """

    def __init__(self, n: int, batch_size: int, seed: int, start_step: int, stop_step: int,
                 rank: int = 0, world_size: int = 1):
        global_batch = batch_size * world_size
        if n < global_batch:
            raise ConfigError(f"dataset has {n} samples, fewer than one global batch "
                              f"({batch_size} x {world_size} ranks)")
        if not 0 <= rank < world_size or not 0 <= start_step <= stop_step:
            raise ValueError(f"bad sampler arguments rank={rank} world={world_size} "
                             f"steps=[{start_step}, {stop_step})")
        self.n, self.batch_size, self.seed = n, batch_size, seed
        self.start_step, self.stop_step = start_step, stop_step
        self.rank, self.world_size = rank, world_size
        self.steps_per_epoch = n // global_batch

    def __len__(self) -> int:
        return self.stop_step - self.start_step

    def _permutation(self, epoch: int) -> torch.Tensor:
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        return torch.randperm(self.n, generator=g)

    def __iter__(self) -> Iterator[list[int]]:
        epoch, perm = -1, None
        for step in range(self.start_step, self.stop_step):
            e, k = divmod(step, self.steps_per_epoch)
            if e != epoch:
                epoch, perm = e, self._permutation(e)
            first = (k * self.world_size + self.rank) * self.batch_size
            yield perm[first:first + self.batch_size].tolist()
