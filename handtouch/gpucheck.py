"""`make gpu-check`: HandTouch stage 1 of configs/full.toml on a CUDA GPU, fed by the real loader.

    python -m handtouch.gpucheck [--dataset DIR] [--work DIR] [--json FILE] [--steps N] [--compile]

For each setting (batch 32 with 8 DataLoader workers, batch 128 with 16; bf16;
`--compile` adds batch 128 under torch.compile) it trains stage 1 for `--steps`
steps and prints one row: samples/s, the share of step time spent waiting for
data, the host's share and the GPU's busy share (CUDA events around each step),
peak GPU memory. Rates are the median of the log windows after the first
(worker start-up, cuDNN autotuning and allocator warm-up stay out).

"GPU span" (CUDA events around each step) is an upper bound on busy time: the span from
the step's first launch to its last kernel's end, gaps included. `--profile
N` measures the real thing on N steps near the end of each setting with
torch.profiler: the GPU kernel milliseconds per step, their share of the
step's wall time, and the kernels that take most of it.

Data: `--dataset` (a committed htdata dataset with split `main`), else one is
built under `--work`: `htdata sample --scale medium` (~9k frames), ingest with
one worker per core, `htdata split --ood-task palm_push --name main`. It is
reused by a later run with the same `--work`.

Needs: a CUDA build of torch and the project's dependencies (pyproject.toml:
numpy, scipy, h5py, OpenEXR, opencv-contrib-python-headless, av, jsonschema,
tqdm, psutil, fsspec); it checks them first and names what is missing. Exits
2 where there is no CUDA device, 3 where a dependency is missing. Results go
to `--json`, default $OUT/gpucheck.json when $OUT is set.

Imports inside functions: the script must say "no GPU" or "missing dependency" on a machine
that lacks them, so the trainer and htdata (which import torch, OpenEXR, cv2 ...) are
imported only after those checks.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

SETTINGS = ((32, 8), (128, 16))          # (batch, DataLoader workers)
MODULES = {"numpy": "numpy", "scipy": "scipy", "h5py": "h5py", "OpenEXR": "OpenEXR",
           "cv2": "opencv-contrib-python-headless", "av": "av", "jsonschema": "jsonschema", "tqdm": "tqdm",
           "psutil": "psutil", "fsspec": "fsspec", "torch": "torch"}
SPLIT, OOD_TASK = "main", "palm_push"


def missing_modules() -> list[str]:
    """pip names of the dependencies that do not import."""
    out = []
    for module, pip_name in MODULES.items():
        try:
            importlib.import_module(module)
        except ImportError:
            out.append(pip_name)
    return out


def build_dataset(work: Path, workers: int | None, scale: str = "medium", log=print) -> Path:
    """The medium sample corpus ingested and split under `work` (reused when already there)."""
    from htdata.cli import main as htdata

    dataset = work / "dataset"
    if (work / ".split_done").exists() and (dataset / "dataset.json").exists():   # written after the split
        log(f"gpu-check: reusing {dataset}")
        return dataset
    t0 = time.perf_counter()
    raws = _sample_formats(work, scale)
    log(f"gpu-check: sample {time.perf_counter() - t0:.0f} s")
    pipelines = [a for fmt in raws for a in ("--pipeline", f"{_pipeline(fmt)}={raws[fmt]}")]
    steps = [
        ("ingest", ["ingest", *(["--workers", str(workers)] if workers is not None else []), "--quiet", *pipelines,
                    str(dataset)]),
        ("split", ["split", str(dataset), "--ood-task", OOD_TASK, "--seed", "0", "--name", SPLIT, "--force"]),
    ]
    for name, argv in steps:
        t0 = time.perf_counter()
        rc = htdata(argv)
        if rc:
            raise SystemExit(f"gpu-check: htdata {name} failed (exit {rc}): htdata {' '.join(argv)}")
        log(f"gpu-check: {name} {time.perf_counter() - t0:.0f} s")
    (work / ".split_done").touch()
    return dataset


def sample_formats() -> tuple[str, ...]:
    """The sample corpus's source formats (htdata.synthetic.corpus.FORMATS), one pipeline each."""
    from htdata.synthetic.corpus import FORMATS

    return FORMATS


def _sample_formats(work: Path, scale: str) -> dict[str, Path]:
    """The medium corpus, one `htdata sample` process per format at once (the writer is serial)."""
    procs = {}
    for fmt in sample_formats():
        argv = [sys.executable, "-m", "htdata.cli", "sample", str(work / f"raw_{fmt}"), "--scale", scale,
                "--formats", fmt, "--reuse", "--quiet"]
        procs[fmt] = subprocess.Popen(argv, stdout=subprocess.DEVNULL)
    failed = [fmt for fmt, p in procs.items() if p.wait() != 0]
    if failed:
        raise SystemExit(f"gpu-check: htdata sample failed for {', '.join(failed)} (under {work})")
    return {fmt: work / f"raw_{fmt}" / fmt for fmt in procs}


def _pipeline(name: str) -> Path:
    from htdata.resources import data_dir

    return data_dir("pipelines") / f"{name}.toml"


def setting_config(dataset: Path, out: Path, batch: int, workers: int, steps: int, compile_: bool,
                   device: str = "cuda", extra: list[str] = ()):
    """configs/full.toml, stage 1 only, for one setting (`extra`: more --set overrides)."""
    from .config import load_train_config
    from .resources import config_file

    over = {"data_root": str(dataset), "out_dir": str(out), "rgb_encoder": "random:0", "split": SPLIT,
            "stages": [1], "device": device, "bf16": True, "batch_size": batch, "workers": workers,
            "compile": compile_, "stage1.steps": steps, "stage1.warmup_steps": min(100, steps // 4),
            "log_every": max(10, steps // 10), "checkpoint_every": 10 * steps, "eval_batch_size": 64}
    return load_train_config(config_file("full"), [f"{k}={json.dumps(v)}" for k, v in over.items()] + list(extra))


class KernelProfile:
    """torch.profiler over `active` steps near the end of a run: GPU kernel time per step, top kernels."""

    def __init__(self, steps: int, active: int):
        from torch.profiler import ProfilerActivity, profile, schedule

        self.active = active
        wait = max(steps - active - 10, 1)     # the run's last steps, after the warm windows
        self.prof = profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA],
                            schedule=schedule(wait=wait, warmup=3, active=active, repeat=1))
        self.t_steps: list[float] = []

    def on_progress(self, _status: dict) -> None:
        self.t_steps.append(time.perf_counter())
        self.prof.step()

    def summary(self) -> dict:
        from torch.autograd import DeviceType

        kernels = [e for e in self.prof.key_averages()
                   if e.device_type == DeviceType.CUDA and not e.is_user_annotation]
        total_us = sum(e.self_device_time_total for e in kernels)
        top = sorted(kernels, key=lambda e: e.self_device_time_total, reverse=True)[:6]
        return {"profiled_steps": self.active, "kernel_ms_per_step": total_us / 1000.0 / self.active,
                "kernels_per_step": sum(e.count for e in kernels) / self.active,
                "top_kernels": [{"name": e.key[:90], "share": e.self_device_time_total / max(total_us, 1)}
                                for e in top]}


def run_setting(dataset: Path, work: Path, batch: int, workers: int, steps: int, compile_: bool,
                device: str = "cuda", extra: list[str] = (), profile_steps: int = 0) -> dict:
    """Stage 1 of configs/full.toml for `steps` steps; one row of the table (+ a kernel profile)."""
    import torch

    from .train import train

    out = work / f"run_b{batch}_w{workers}{'_compile' if compile_ else ''}"
    cfg = setting_config(dataset, out, batch, workers, steps, compile_, device, extra)
    cuda = cfg.device.startswith("cuda")
    if out.exists():
        import shutil
        shutil.rmtree(out)
    records: list[dict] = []
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    prof = KernelProfile(steps, profile_steps) if profile_steps and cuda else None
    t0 = time.perf_counter()
    if prof is None:
        metrics = train(cfg, on_record=records.append)
    else:
        with prof.prof:
            metrics = train(cfg, on_record=records.append, on_progress=prof.on_progress)
    wall = time.perf_counter() - t0
    windows = [r for r in records if r.get("stage") == 1 and "samples_per_s" in r][1:] or \
        [r for r in records if r.get("stage") == 1 and "samples_per_s" in r]

    def med(key):
        vals = [r[key] for r in windows if key in r]
        return float(statistics.median(vals)) if vals else float("nan")

    stage = metrics["stages"]["1"]
    return {"batch": batch, "workers": workers, "compile": compile_, "steps": steps, "bf16": True,
            "samples_per_s": med("samples_per_s"), "steps_per_s": med("steps_per_s"),
            "data_wait_share": med("data_wait_share"), "host_share": med("host_share"),
            "gpu_busy_share": med("device_busy_share"), "whole_stage_samples_per_s": stage["samples_per_s"],
            "timing": stage.get("timing"), "final_loss": stage["final"].get("loss"),
            "peak_gpu_mem_gb": torch.cuda.max_memory_allocated() / 2 ** 30 if cuda else float("nan"),
            "wall_s": wall, **({"profile": prof.summary()} if prof is not None else {})}


def profile_lines(row: dict) -> list[str]:
    """The kernel profile of one row, in words ([] without one)."""
    prof = row.get("profile")
    if not prof:
        return []
    step_ms = 1000.0 / row["steps_per_s"] if row.get("steps_per_s") else float("nan")
    lines = [f"batch {row['batch']}{' compiled' if row['compile'] else ''}: GPU kernels "
             f"{prof['kernel_ms_per_step']:.1f} ms per step ({prof['kernels_per_step']:.0f} kernels) of a "
             f"{step_ms:.1f} ms step = {prof['kernel_ms_per_step'] / step_ms:.0%} busy "
             f"(torch.profiler, {prof['profiled_steps']} steps; the profiler slows the host a little)"]
    lines += [f"    {k['share']:5.1%}  {k['name']}" for k in prof["top_kernels"]]
    return lines


def _fmt(v, spec: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def table(rows: list[dict]) -> str:
    head = "| batch | workers | compile | samples/s | steps/s | data wait | host | GPU span | GPU mem GB | wall s |"
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['batch']} | {r['workers']} | {'yes' if r['compile'] else 'no'} | {r['error']} |")
            continue
        lines.append(f"| {r['batch']} | {r['workers']} | {'yes' if r['compile'] else 'no'} | "
                     f"{_fmt(r['samples_per_s'], '.0f')} | {_fmt(r['steps_per_s'], '.1f')} | "
                     f"{_fmt(r['data_wait_share'], '.0%')} | {_fmt(r['host_share'], '.0%')} | "
                     f"{_fmt(r['gpu_busy_share'], '.0%')} | {_fmt(r['peak_gpu_mem_gb'], '.1f')} | "
                     f"{_fmt(r['wall_s'], '.0f')} |")
    return "\n".join(lines)


def _json_safe(v):
    """NaN -> None (strict JSON)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_json_safe(x) for x in v]
    return v


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m handtouch.gpucheck", description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help=f"a committed dataset with split {SPLIT!r} (default: build one)")
    parser.add_argument("--work", type=Path, default=Path(os.environ.get("HT_GPUCHECK_WORK", "/tmp/ht_gpucheck")),
                        help="scratch folder: the built dataset and the runs (default /tmp/ht_gpucheck)")
    out_env = os.environ.get("OUT")
    parser.add_argument("--json", type=Path, default=Path(out_env) / "gpucheck.json" if out_env else None,
                        help="write the results here (default $OUT/gpucheck.json when $OUT is set)")
    parser.add_argument("--steps", type=int, default=300, help="stage-1 steps per setting (default 300)")
    parser.add_argument("--compile", action="store_true", help="also run batch 128 under torch.compile")
    parser.add_argument("--ingest-workers", type=int, default=None,
                        help="htdata ingest --workers of the dataset built (default: ingest's, every usable core)")
    parser.add_argument("--scale", default="medium", choices=("tiny", "small", "medium"),
                        help="sample corpus scale of the dataset built (default medium, ~9k frames)")
    parser.add_argument("--settings", default=",".join(f"{b}:{w}" for b, w in SETTINGS),
                        help="BATCH:WORKERS,... (default %(default)s)")
    parser.add_argument("--skip-after-s", type=float, default=330.0,
                        help="start no further setting after this many seconds in all (default 330)")
    parser.add_argument("--device", default="cuda", help="cuda (default), or cpu to try the script itself")
    parser.add_argument("--profile", type=int, default=0, metavar="N",
                        help="also profile N steps near the end of each setting (GPU kernel time per step)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="more config overrides, e.g. --set model.depth=2")
    args = parser.parse_args(argv)
    try:
        import torch
    except ImportError:
        print("gpu-check: torch is not installed (pip install torch, a CUDA build)", file=sys.stderr)
        return 3
    if args.device != "cpu" and not torch.cuda.is_available():
        print(f"gpu-check: no CUDA device (torch {torch.__version__}, CUDA build {torch.version.cuda}): "
              "nothing measured; run it on a machine with an NVIDIA GPU", file=sys.stderr)
        return 2
    missing = missing_modules()
    if missing:
        print(f"gpu-check: missing dependencies: {', '.join(missing)} (pip install {' '.join(missing)}, or "
              "pip install -e .)", file=sys.stderr)
        return 3
    if args.steps < 20:
        parser.error("--steps must be >= 20 (rates come from log windows after the first)")
    args.work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    dataset = args.dataset or build_dataset(args.work, args.ingest_workers, args.scale)
    build_s = time.perf_counter() - t0
    device = torch.cuda.get_device_name(0) if args.device != "cpu" else "cpu"
    print(f"gpu-check: {device}, {os.cpu_count()} CPUs, torch {torch.__version__}; dataset {dataset} "
          f"({build_s:.0f} s to build)", flush=True)
    pairs = [tuple(int(x) for x in s.split(":")) for s in args.settings.split(",")]
    settings = [(b, w, False) for b, w in pairs] + ([(pairs[-1][0], pairs[-1][1], True)] if args.compile else [])
    rows = []
    for batch, workers, comp in settings:
        if time.perf_counter() - t0 > args.skip_after_s:
            rows.append({"batch": batch, "workers": workers, "compile": comp,
                         "error": f"skipped: {args.skip_after_s:.0f} s spent (--skip-after-s)"})
        else:
            try:
                rows.append(run_setting(dataset, args.work, batch, workers, args.steps, comp, args.device, args.set,
                                        args.profile))
            except Exception as e:   # noqa: BLE001  (a compile that fails on this machine is a result, not a crash)
                if not comp:
                    raise
                rows.append({"batch": batch, "workers": workers, "compile": comp,
                             "error": f"torch.compile failed: {type(e).__name__}: {str(e).splitlines()[0][:200]}"})
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    print(table(rows), flush=True)
    kernels = [line for r in rows for line in profile_lines(r)]
    print("\n".join(kernels), flush=True)
    result = {"device": device, "cpus": os.cpu_count(), "torch": torch.__version__, "dataset": str(dataset),
              "dataset_build_s": build_s, "rows": rows}
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(_json_safe(result), indent=2))
        args.json.with_suffix(".md").write_text(f"{device}, {os.cpu_count()} CPUs, torch {torch.__version__}; "
                                                f"stage 1 of configs/full.toml, bf16, {args.steps} steps\n\n"
                                                + table(rows) + "\n\n" + "\n".join(kernels) + "\n")
        print(f"gpu-check: wrote {args.json} and {args.json.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
