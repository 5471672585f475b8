"""The `htdata bench` section "training": HandTouch stage 1 steps/s in fp32 vs bf16 autocast.

htdata never imports handtouch; `htdata bench` finds this section through the entry
point group "htdata.bench_sections" (pyproject.toml: training =
"handtouch.benchmark:training_section") and calls `training_section(ctx)` with
ctx.dataset (an ingested sample dataset), ctx.work (scratch folder), ctx.quick and
ctx.seed. It returns JSON-able results; "markdown" is rendered verbatim in REPORT.md.

Each row splits a step (handtouch.steploop.StepTimes): data wait (here the
in-process decode: workers 0), host (the step's Python and, on a CPU, its
compute) and, on CUDA, device busy time from CUDA events.

Both runs use the shipped smoke config (`handtouch.resources.config_file`), the same
steps and seed. DataLoader workers are 0 so both decode in the training process and
the ratio compares the model step, not worker scheduling on 2 shared cores.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

from .config import load_train_config
from .resources import config_file
from .train import train

CONFIG = "smoke"
STEPS, QUICK_STEPS = 40, 2
WARMUP_STEPS = 2        # the untimed warm-up run of a full benchmark


def _toml(value: Any) -> str:
    """An override value as TOML (a JSON string is a valid TOML basic string)."""
    return json.dumps(str(value)) if isinstance(value, (str, Path)) else json.dumps(value)


def stage1_run(dataset: Path, out: Path, steps: int, bf16: bool, seed: int = 0,
               batch_size: int | None = None) -> dict:
    """Train stage 1 only for `steps` steps into a fresh `out`; one row of the table."""

    if out.exists():
        shutil.rmtree(out)
    overrides = {"data_root": dataset, "out_dir": out, "stages": [1], "split": "", "workers": 0, "threads": 0,
                 "seed": seed, "bf16": bf16, "stage1.steps": steps,
                 "stage1.warmup_steps": max(1, min(10, steps // 3)), "log_every": steps,
                 "checkpoint_every": steps + 1}
    if batch_size is not None:
        overrides["batch_size"] = batch_size
    cfg = load_train_config(config_file(CONFIG), [f"{k}={_toml(v)}" for k, v in overrides.items()])
    metrics = train(cfg)
    stage = metrics["stages"]["1"]
    timing = stage.get("timing") or {}
    per_step = {f"{k[:-2]}_ms_per_step": 1000.0 * timing[k] / max(timing.get("steps", 0), 1)
                for k in ("wall_s", "data_wait_s", "host_s", "device_s") if k in timing}
    return {**per_step, "data_wait_share": float(timing.get("data_wait_share", float("nan"))),
            "precision": "bf16 autocast" if bf16 else "fp32", "steps": int(stage["steps"]),
            "batch_size": cfg.batch_size, "seconds": float(stage["seconds"]),
            "steps_per_s": float(stage["steps_per_s"]), "samples_per_s": float(stage["samples_per_s"]),
            "final_loss": float(stage["final"].get("loss", float("nan"))),
            "recon_rmse": float(metrics["recon_rmse"]),
            "eval_source": metrics.get("heldout_source", "")}


def training_rows(dataset: Path, work: Path, steps: int, seed: int = 0, batch_size: int | None = None,
                  warmup: bool = True) -> dict:
    """fp32 then bf16 autocast, same steps and seed; ratios bf16 / fp32."""
    if warmup:   # first run in a process pays one-off costs (allocator, kernels): keep them out of fp32's number
        stage1_run(dataset, work / "train_warmup", WARMUP_STEPS, bf16=False, seed=seed, batch_size=batch_size)
    rows = [stage1_run(dataset, work / f"train_{p}", steps, bf16=p == "bf16", seed=seed, batch_size=batch_size)
            for p in ("fp32", "bf16")]
    return {"config": str(config_file(CONFIG)), "rows": rows, "warmup_run": warmup,
            "bf16_speedup": rows[1]["steps_per_s"] / rows[0]["steps_per_s"],
            "recon_rmse_ratio_bf16_fp32": rows[1]["recon_rmse"] / rows[0]["recon_rmse"]}


COLUMNS = (("precision", "precision"), ("steps", "steps"), ("batch_size", "batch"), ("steps_per_s", "steps/s"),
           ("samples_per_s", "samples/s"), ("wall_ms_per_step", "ms/step"), ("data_wait_ms_per_step", "data wait ms"),
           ("host_ms_per_step", "host ms"), ("device_ms_per_step", "device ms"), ("final_loss", "final loss"),
           ("recon_rmse", "recon RMSE"))


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.3g}"
    return str(v)


def render_markdown(result: dict) -> str:
    """The section's REPORT.md body: one row per precision, then the ratios in words."""
    lines = [f"Stage 1 of the `{CONFIG}` config, fp32 vs bf16 autocast, same steps and seed. Per step: "
             "data wait (in-process decode, workers 0), host (the step's Python and, on a CPU, its compute), "
             "device (CUDA events; - on a CPU).", "",
             "| " + " | ".join(h for _, h in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(_cell(r.get(k)) for k, _ in COLUMNS) + " |" for r in result["rows"]]
    lines += ["", f"bf16 / fp32 speed: {result['bf16_speedup']:.2f}x; recon RMSE ratio "
              f"{result['recon_rmse_ratio_bf16_fp32']:.3f} (held-out batch: {result['rows'][0]['eval_source']}). "
              + ("An untimed 2-step warm-up run came first." if result["warmup_run"] else
                 "No warm-up run: fp32 (run first) carries one-off start-up costs.")]
    return "\n".join(lines) + "\n"


def training_section(ctx) -> dict:
    """Entry point of the "training" bench section (see the module docstring for ctx)."""
    steps = QUICK_STEPS if ctx.quick else STEPS
    result = training_rows(Path(ctx.dataset), Path(ctx.work) / "training", steps, seed=ctx.seed,
                           warmup=not ctx.quick)
    result["markdown"] = render_markdown(result)
    return result
