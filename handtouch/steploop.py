"""The trainer's step loop: one stage's steps, with no host sync between logs, and where the time goes.

A GPU runs ahead of the Python that feeds it only while nothing reads a value
back: `float(loss)`, `if not torch.isfinite(loss)`, `.item()`, a boolean-mask
index or `bincount` each stop the host until the device has caught up, and
the next step's launch overhead then adds to the device's work instead of
hiding under it. So the loop keeps the logged terms, the non-finite check and
the VQ statistics as device tensors, summed over the log window, and reads
them back once every `log_every` steps (a non-finite loss is reported there,
naming its first step). Batches arrive pinned from the DataLoader and are
copied with non_blocking; constants="once" batches are expanded on the device
(`htdata.read.torchitems.expand_batch`).

`StepTimes` splits each window's wall time: data wait (blocked on the
loader), host (the Python of the step: copies, launches, optimiser; on a CPU
device this includes the compute) and, on CUDA, device busy time from a pair
of CUDA events per step, read at log time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import torch
import torch.nn as nn

from htdata.read import keys
from htdata.read.torchitems import ItemConstants, expand_batch

from .config import TrainConfig
from .distributed import DistEnv, mean_across_ranks
from .progress import Rate
from .stages import Stage, StepInfo


def lr_at(step: int, total: int, base: float, warmup: int) -> float:
    """Linear warmup then cosine decay to 10% of base."""
    if warmup and step < warmup:
        return base * (step + 1) / warmup
    span = max(total - warmup, 1)
    return base * (0.1 + 0.45 * (1 + math.cos(math.pi * min(step - warmup, span) / span)))


def to_device(batch: dict, device: torch.device, constants: ItemConstants | None = None) -> dict:
    """The batch on `device` (non_blocking: the loader pins it on CUDA), expanded if its items were packed."""
    batch = {k: v.to(device, non_blocking=True) if torch.is_tensor(v) else v for k, v in batch.items()}
    if keys.IDS in batch:
        if constants is None:
            raise ValueError("a constants='once' batch needs its dataset's constants() to expand it: give "
                             "TrainData(constants=dataset.constants()) when the dataset is wrapped")
        batch = expand_batch(batch, constants)
    return batch


def autocast(cfg: TrainConfig, device: torch.device):
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16, enabled=cfg.bf16)


def make_optimizer(params: list[nn.Parameter], lr: float, weight_decay: float,
                   device: torch.device) -> torch.optim.Optimizer:
    """AdamW; fused (one kernel for every parameter) on CUDA."""
    return torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay, fused=device.type == "cuda")


@dataclass
class StepTimes:
    """Seconds per part of the step, summed over the steps timed (see the module docstring)."""
    steps: int = 0
    wall_s: float = 0.0
    data_wait_s: float = 0.0
    host_s: float = 0.0
    device_s: float | None = None      # CUDA only
    _events: list = field(default_factory=list, repr=False)

    def start_device(self, device: torch.device):
        if device.type != "cuda":
            return None
        ev = torch.cuda.Event(enable_timing=True)
        ev.record()
        return ev

    def end_device(self, start) -> None:
        if start is not None:
            end = torch.cuda.Event(enable_timing=True)
            end.record()
            self._events.append((start, end))

    def collect(self) -> None:
        """Read the CUDA events recorded so far (waits for the last one: call at log time only)."""
        if self._events:
            self._events[-1][1].synchronize()
            self.device_s = (self.device_s or 0.0) + sum(a.elapsed_time(b) for a, b in self._events) / 1000.0
            self._events.clear()

    def snapshot(self) -> tuple[float, float, float, float]:
        """(wall, data wait, host, device) seconds so far (collects the CUDA events)."""
        self.collect()
        return self.wall_s, self.data_wait_s, self.host_s, self.device_s or 0.0

    def shares_since(self, before: tuple[float, float, float, float]) -> dict:
        """Shares of the wall time since `before` (a snapshot): data wait, host and (CUDA) device busy."""
        now = self.snapshot()
        wall = now[0] - before[0]
        out = {"data_wait_share": (now[1] - before[1]) / wall if wall > 0 else 0.0,
               "host_share": (now[2] - before[2]) / wall if wall > 0 else 0.0}
        if self.device_s is not None:
            out["device_busy_share"] = (now[3] - before[3]) / wall if wall > 0 else 0.0
        return out

    def as_dict(self) -> dict:
        self.collect()
        out = {"steps": self.steps, "wall_s": self.wall_s, "data_wait_s": self.data_wait_s, "host_s": self.host_s,
               "data_wait_share": self.data_wait_s / self.wall_s if self.wall_s > 0 else 0.0}
        if self.device_s is not None:
            out["device_s"] = self.device_s
            out["device_busy_share"] = self.device_s / self.wall_s if self.wall_s > 0 else 0.0
        return out


@dataclass
class StageRun:
    """The pieces one stage's step loop works with."""
    stage: Stage
    step_loss: nn.Module          # StageLoss(stage, model), DDP-wrapped under torchrun (maybe compiled)
    opt: torch.optim.Optimizer
    params: list[nn.Parameter]
    cfg: TrainConfig
    env: DistEnv
    write: Callable[[dict], None]             # a log record (rank 0)
    constants: ItemConstants | None = None    # on the device, for constants="once" batches
    times: StepTimes = field(default_factory=StepTimes)
    progress: Callable[[dict], None] | None = None   # every step: handtouch.progress.Rate's report (no sync)


class _Window:
    """Logged terms summed on the device over the steps since the last log; first non-finite step."""

    def __init__(self, device: torch.device):
        self.device = device
        self.names: list[str] | None = None
        self.sums: torch.Tensor | None = None
        self.steps = 0
        self.bad_step = torch.full((), -1, dtype=torch.long, device=device)

    def add(self, step: int, loss: torch.Tensor, terms: dict[str, torch.Tensor]) -> None:
        values = torch.stack([loss.detach().float(), *(v.detach().float().reshape(()) for v in terms.values())])
        if self.names is None:
            self.names = ["loss", *terms]
        self.sums = values if self.sums is None else self.sums + values
        bad = ~torch.isfinite(loss.detach())
        self.bad_step = torch.where(bad & (self.bad_step < 0), torch.full_like(self.bad_step, step), self.bad_step)
        self.steps += 1

    def read(self, stage: int) -> dict[str, float]:
        """The window's means (one read-back); raises on a non-finite loss in it."""
        bad = int(self.bad_step)
        if bad >= 0:
            raise FloatingPointError(f"stage {stage} step {bad}: non-finite loss")
        means = (self.sums / max(self.steps, 1)).tolist()
        out = dict(zip(self.names, means))
        self.sums, self.steps = None, 0
        return out


def _timed(loader: Iterable, times: StepTimes):
    """Yield the loader's batches, adding the time blocked in it to times.data_wait_s."""
    it = iter(loader)
    while True:
        t0 = time.perf_counter()
        try:
            batch = next(it)
        except StopIteration:
            return
        times.data_wait_s += time.perf_counter() - t0
        yield batch


def train_steps(run: StageRun, loader: Iterable, start: int,
                checkpoint: Callable[[int], None]) -> tuple[dict[str, float], int]:
    """Steps [start, steps): the generic loop. -> (last logged mean losses, last step index)."""
    stage, cfg, env, opt, times = run.stage, run.cfg, run.env, run.opt, run.times
    n, total = stage.number, stage.cfg.steps
    window = _Window(env.device)
    last: dict[str, float] = {}
    step = start
    t_window = t_step = time.perf_counter()
    at_window = times.snapshot()
    rate = Rate(start)
    for step, batch in zip(range(start, total), _timed(loader, times)):
        t_host = time.perf_counter()
        ev = times.start_device(env.device)
        batch = to_device(batch, env.device, run.constants)
        for group in opt.param_groups:
            group["lr"] = lr_at(step, total, stage.cfg.lr, stage.cfg.warmup_steps)
        batch = stage.prepare(batch, StepInfo(step, total, env.rank))
        with autocast(cfg, env.device):
            loss, loss_dict = run.step_loss(batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(run.params, stage.cfg.grad_clip)
        opt.step()
        window.add(step, loss, loss_dict)
        times.end_device(ev)
        now = time.perf_counter()
        times.host_s += now - t_host
        times.wall_s += now - t_step
        times.steps += 1
        t_step = now
        done_steps = step + 1
        if run.progress is not None:
            run.progress(rate.report(f"stage {n}", done_steps, total, cfg.batch_size * env.world_size))
        if done_steps % cfg.log_every == 0 or done_steps == total:
            steps_in_window = window.steps
            means = window.read(n)          # the one host sync of the window
            last = mean_across_ranks(means, env)
            elapsed = time.perf_counter() - t_window
            sps = steps_in_window / max(elapsed, 1e-9)
            shares = times.shares_since(at_window)
            if env.is_main:
                run.write({"stage": n, "step": done_steps, "lr": opt.param_groups[0]["lr"], **last,
                           "steps_per_s": sps, "samples_per_s": sps * cfg.batch_size * env.world_size,
                           "eta_s": (total - done_steps) / max(sps, 1e-9), **shares})
            t_window, at_window = time.perf_counter(), times.snapshot()
        if done_steps % cfg.checkpoint_every == 0 and done_steps < total:
            checkpoint(done_steps)
        t_step = time.perf_counter()   # checkpoints and logs are not a step's time
    return last, step
