"""The held-out gate scored in a forked process while the smoke evaluates (handtouch.smoke).

After training, the smoke's later phases read the trained model only: HT-Bench's evaluation, the
checks and the misalignment controls, and the held-out gate (handtouch.contact_gate: three
RGB-to-tactile passes over up to 800 frames per part, about half of the time after training).
Two threads in one process gave 1.6x one on the gate (19.1 s against 30.4 s), two processes on
the two cores of the same machine 1.96x: so where two cores are free the gate runs in a second
process on one thread while this one evaluates on the other, and where fewer are free it runs
here after the evaluation, as before. The values are the same computation on one thread instead of
two (float sums in another order: the gate's figures agree to ~1e-7).

The process is forked, not spawned: it starts with the trained model, the decoded frames and the
dataset's records already in memory. It prints nothing and writes its console to /dev/null (another
thread of ours, the heartbeat, may hold the console's lock at the fork, and its buffer may hold lines
the parent prints itself) and sends its result, or its error as words, through a pipe.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import time
import traceback

import numpy as np
import torch

from handtouch.contact_gate import GateConfig, gate, score_part
from handtouch.rgb_pretrain import episode_fps
from handtouch.smokedata import SPLIT_NAME


def heldout_gate(model, args: argparse.Namespace, frames: dict) -> tuple[list[dict], dict]:
    """The held-out gate's checks and report (handtouch.contact_gate) for `model` on the parts' decoded
    `frames` (contact_gate.decode_part)."""
    cfg = GateConfig(max_frames=args.gate_frames, seed=args.seed)
    tables = {p: score_part(model, args.dataset, SPLIT_NAME, p, cfg, frames[p]) for p in ("test", "ood")}
    return gate(tables, args.ood_task, args.stress_task or None, typical_fps(args.dataset))


def typical_fps(dataset) -> float:
    """The median episode fps (30 where no episode has one): the lag check's frames <-> seconds."""
    fps = episode_fps(dataset)
    return float(np.median(fps[fps > 0])) if (fps > 0).any() else 30.0


class GateJob:
    """The held-out gate of one trained model: beside this process (`start(..., beside=True)`) or, when
    `result` is asked, in it. `close` stops a process still running (a failed run must not leave it)."""

    def __init__(self, model, args: argparse.Namespace, frames: dict, process=None, conn=None):
        self._model, self._args, self._frames = model, args, frames
        self._process, self._conn = process, conn
        self.seconds: float | None = None      # the gate's own wall seconds, wherever it ran

    @classmethod
    def start(cls, model, args: argparse.Namespace, frames: dict, beside: bool) -> "GateJob":
        if not beside:
            return cls(model, args, frames)
        ctx = multiprocessing.get_context("fork")
        parent_end, child_end = ctx.Pipe(duplex=False)
        process = ctx.Process(target=_child, args=(model, args, frames, child_end), name="smoke-gate", daemon=True)
        process.start()
        child_end.close()
        return cls(model, args, frames, process, parent_end)

    @property
    def beside(self) -> bool:
        return self._process is not None

    def result(self) -> tuple[list[dict], dict]:
        """-> (checks, report) of `heldout_gate`. Raises SystemExit naming the forked process's error."""
        if self._process is None:
            t = time.perf_counter()
            out = heldout_gate(self._model, self._args, self._frames)
            self.seconds = time.perf_counter() - t
            return out
        try:
            status, payload, self.seconds = self._conn.recv()
        except EOFError:        # the process died without a word (killed, out of memory)
            status, payload = "error", "the process ended without a result"
        self._process.join()
        self._conn.close()
        if status != "ok":
            raise SystemExit(f"smoke: the held-out gate, scored beside the evaluation, failed: {payload} "
                             f"(exit code {self._process.exitcode})")
        return payload

    def close(self) -> None:
        if self._process is not None and self._process.is_alive():
            self._process.terminate()
            self._process.join()


def _child(model, args: argparse.Namespace, frames: dict, conn) -> None:
    """The forked process: the gate on one thread, then one message (status, result or error, seconds)."""
    t = time.perf_counter()
    # the console's buffers as the fork left them (maybe mid-write by the heartbeat, maybe holding its
    # unflushed lines) are never touched: exiting flushes these instead
    sys.stdout = sys.stderr = open(os.devnull, "w")
    try:
        torch.set_num_threads(1)
        conn.send(("ok", heldout_gate(model, args, frames), time.perf_counter() - t))
    except BaseException as exc:     # every failure reaches the parent as words, not a silent exit
        conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}", time.perf_counter() - t))
    finally:
        conn.close()
