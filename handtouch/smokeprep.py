"""The smoke's evaluation inputs, built in a second process while the model trains.

Training runs on one compute thread and one loader worker (configs/smoke.toml: `threads = 1`,
`workers = 1`), so the second core of the 2-core budget is mostly idle for its ~75 s. What
the later phases read depends only on the dataset, the split and the RGB probes, not on
the model being trained:
    probes      the control probes (rgb_pretrain.REQUIRED_CONTROLS: the shuffled one), trained
                here on CONTROL_PROBE_THREADS; only the aligned probe, the frozen RGB encoder
                training needs, is trained before it,
    prepared    HT-Bench's decoded items, masks and SSIM/retrieval references (bench.items.prepare),
    references  HT-Bench's scores of the reference predictors (all zeros, copy-last) on them,
    probe       the RGB probes' control scores per part and pairing (rgb_pretrain.control_scores),
    gate        the held-out gate's decoded frames per part (contact_gate.decode_part).
`EvalInputs.start` builds them on that core, in a *spawned* process with one torch thread
(spawned, so that no thread of ours is running when the trainer's DataLoader forks its
worker), and `EvalInputs.result` waits for them. They come back through one file in the
run folder, written by torch.save and deleted once read. The values are the ones the
smoke computed in its own process before (same items, seeds and code), but for the thread
counts: the SSIM reference's float sums (which differed between an idle and a busy machine
before too) and the control probe's, whose weights depend on its thread count: 1 here, so
it is a cache key apart from a 2-thread one (rgb_pretrain.cache_key).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import torch

from handtouch.bench.evaluate import evaluate
from handtouch.bench.items import EvalConfig, load_part, prepare
from handtouch.bench.references import CopyLastModel, ZerosModel
from handtouch.contact_gate import GateConfig, decode_part
from handtouch.probeitems import load_items
from handtouch.rgb_pretrain import REQUIRED_CONTROLS, RGBPretrainConfig, control_scores, ensure_probes

PARTS = ("test", "ood")
INPUTS_FILE = ".eval_inputs.pt"
# One core beside training. A control's only duty is to score far from the aligned probe (shuffled
# 0.78 of all zeros against aligned 0.42 + CONTROL_MARGIN 0.11 at seed 0), which its thread count
# does not change; two threads here would oversubscribe the core training runs on.
CONTROL_PROBE_THREADS = 1


@dataclass(frozen=True)
class InputsRequest:
    """What the child builds: the dataset and split, the evaluation / probe / gate settings."""
    dataset: Path
    split: str
    eval_cfg: EvalConfig
    pre_cfg: RGBPretrainConfig
    gate_cfg: GateConfig
    probes: dict[str, Path]     # the probes trained so far: {"aligned": path}
    probe_dir: Path             # the probes' cache folder (rgb_pretrain.ensure_probes)
    out_file: Path

    @property
    def control_cfg(self) -> RGBPretrainConfig:
        return dataclasses.replace(self.pre_cfg, threads=CONTROL_PROBE_THREADS)


def build_inputs(req: InputsRequest) -> dict:
    """The child's work (module docstring); -> {"file", "seconds": {what: wall s}}.

    Raises what the readers raise (a damaged shard names its file), re-raised in the parent by `result`.
    """
    torch.set_num_threads(1)      # the core training leaves idle, not both
    seconds, t = {}, time.perf_counter()
    probes = {**req.probes, **ensure_probes(req.dataset, req.split, req.probe_dir, req.control_cfg,
                                            pairings=REQUIRED_CONTROLS)}
    seconds["control_probes"], t = time.perf_counter() - t, time.perf_counter()
    prepared = prepare({p: load_part(req.dataset, req.split, p) for p in PARTS}, cfg=req.eval_cfg)
    seconds["prepared"], t = time.perf_counter() - t, time.perf_counter()
    references = {m.name: evaluate(m, prepared) for m in (ZerosModel(), CopyLastModel())}
    seconds["references"], t = time.perf_counter() - t, time.perf_counter()
    items = {p: load_items(req.dataset, req.split, p, req.pre_cfg) for p in PARTS}
    probe = control_scores(probes, items, req.pre_cfg)
    del items
    seconds["probe"], t = time.perf_counter() - t, time.perf_counter()
    gate = {p: decode_part(req.dataset, req.split, p, req.gate_cfg) for p in PARTS}
    seconds["gate"], t = time.perf_counter() - t, time.perf_counter()
    tmp = req.out_file.with_name(req.out_file.name + ".tmp")
    torch.save({"prepared": prepared, "references": references, "probe": probe, "gate": gate, "probes": probes},
               tmp)
    os.replace(tmp, req.out_file)
    seconds["write"] = time.perf_counter() - t
    return {"file": str(req.out_file), "seconds": seconds}


@dataclass
class Inputs:
    prepared: dict
    references: dict             # {reference model name: evaluate(...)}
    probe: dict
    gate: dict
    probes: dict[str, Path]      # every probe: the aligned one and the controls
    seconds: dict[str, float]    # the child's wall seconds per input, beside training


class EvalInputs:
    """One background build of the evaluation inputs (module docstring). `close` stops a child still
    running (a failed or interrupted run must not leave it working, nor wait for it)."""

    def __init__(self, process, conn, out_file: Path):
        self._process, self._conn, self._out_file = process, conn, out_file
        self._t0 = time.perf_counter()

    @classmethod
    def start(cls, req: InputsRequest) -> "EvalInputs":
        ctx = multiprocessing.get_context("spawn")
        parent_end, child_end = ctx.Pipe(duplex=False)
        process = ctx.Process(target=_child, args=(req, child_end), name="smoke-eval-inputs", daemon=True)
        process.start()
        child_end.close()
        return cls(process, parent_end, req.out_file)

    def result(self) -> Inputs:
        """Wait for the child and load what it built. Raises SystemExit naming the child's error."""
        try:
            status, payload = self._conn.recv()
        except EOFError:        # the child died without a word (killed, out of memory)
            self._process.join()
            status, payload = "error", f"the process ended with exit code {self._process.exitcode}"
        self._process.join()
        if status != "ok":
            raise SystemExit(f"smoke: preparing the evaluation inputs beside training failed: {payload}")
        try:
            # our own file of this run; mmap: pages are read as the phases use them
            data = torch.load(payload["file"], weights_only=False, mmap=True)
        finally:
            self._out_file.unlink(missing_ok=True)
        return Inputs(data["prepared"], data["references"], data["probe"], data["gate"], data["probes"],
                      {**payload["seconds"], "since_start": time.perf_counter() - self._t0})

    def close(self) -> None:
        if self._process.is_alive():
            self._process.terminate()
            self._process.join()
        self._conn.close()
        self._out_file.unlink(missing_ok=True)
        self._out_file.with_name(self._out_file.name + ".tmp").unlink(missing_ok=True)


def _child(req: InputsRequest, conn) -> None:
    """The spawned process: build_inputs, then one message ("ok", result) or ("error", what failed)."""
    try:
        conn.send(("ok", build_inputs(req)))
    except BaseException as exc:     # every failure reaches the parent as words, not a silent exit
        conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    finally:
        conn.close()
