"""HandTouch stage 1 (smoke config) steps/s in fp32 vs bf16 autocast, same steps, same seed.

DataLoader workers are 0 so both runs decode in the training process and the
ratio compares the model step, not worker scheduling on 2 shared cores.
"""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

from htdata.resources import PROJECT_ROOT

SMOKE_CONFIG = PROJECT_ROOT / "configs" / "smoke.toml"


def stage1_run(dataset: Path, out: Path, steps: int, bf16: bool, batch_size: int | None = None) -> dict:
    from handtouch.config import load_train_config
    from handtouch.train import train

    if out.exists():
        shutil.rmtree(out)
    overrides = [f'data_root="{dataset}"', f'out_dir="{out}"', "stages=[1]", "split=\"\"", "workers=0", "threads=0",
                 f"bf16={'true' if bf16 else 'false'}", f"stage1.steps={steps}",
                 f"stage1.warmup_steps={max(1, min(10, steps // 3))}", f"log_every={steps}",
                 f"checkpoint_every={steps + 1}"]
    if batch_size is not None:
        overrides.append(f"batch_size={batch_size}")
    cfg = load_train_config(SMOKE_CONFIG, overrides)
    with contextlib.redirect_stdout(io.StringIO()):   # the trainer logs JSON lines to stdout
        metrics = train(cfg)
    stage = metrics["stages"]["1"]
    return {"precision": "bf16 autocast" if bf16 else "fp32", "steps": int(stage["steps"]),
            "batch_size": cfg.batch_size, "seconds": float(stage["seconds"]),
            "steps_per_s": float(stage["steps_per_s"]), "samples_per_s": float(stage["samples_per_s"]),
            "final_loss": float(stage["final"].get("loss", float("nan"))),
            "recon_rmse": float(metrics["recon_rmse"]),
            "eval_source": metrics.get("heldout_source", "")}


def training_rows(dataset: Path, work: Path, steps: int, batch_size: int | None = None,
                  warmup: bool = True) -> dict:
    if warmup:   # first run in a process pays one-off costs (allocator, kernels): keep them out of fp32's number
        stage1_run(dataset, work / "train_warmup", 2, bf16=False, batch_size=batch_size)
    rows = [stage1_run(dataset, work / f"train_{p}", steps, bf16=p == "bf16", batch_size=batch_size)
            for p in ("fp32", "bf16")]
    return {"config": str(SMOKE_CONFIG), "rows": rows, "warmup_run": warmup,
            "bf16_speedup": rows[1]["steps_per_s"] / rows[0]["steps_per_s"],
            "recon_rmse_ratio_bf16_fp32": rows[1]["recon_rmse"] / rows[0]["recon_rmse"]}
