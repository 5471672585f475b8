"""`python -m handtouch.smoke --out runs/smoke`: the end-to-end smoke run (`make train-smoke`).

1. data: `htdata sample RAW --scale small` if RAW has no corpus; `htdata ingest`
   of all three pipelines into DATASET if it has no dataset.json; `htdata split
   --ood-task palm_push --name smoke` (task palm_push held out as ood);
2. train HandTouch (vit) and the baselines (cnn, resnet18) with the SAME config
   and budget (configs/smoke.toml, only model.encoder overridden);
3. HT-Bench on the test and ood parts (at most --max-items items per part) for
   the three models and the reference predictors (zeros-ref, copy-last-ref);
4. write OUT/results.json, OUT/results.md, OUT/predictions.png;
5. assert that HandTouch learned (exit 1 with the failed checks otherwise):
   - stage-1 reconstruction F-RMSE (test) <= RECON_RATIO x the all-zeros predictor's,
   - retrieval Hit@1 (test) > chance 1/20,
   - codebook perplexity on test maps >= PERPLEXITY_FLOOR codes.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from handtouch.bench.evaluate import (CopyLastModel, EvalConfig, PreparedPart, ZerosModel, collect_examples, evaluate,
                                      load_part, prepare)
from handtouch.bench.report import render_predictions, write_results

ENCODERS = ("vit", "cnn", "resnet18")     # HandTouch first; the other two are the baselines
RAW_FORMATS = ("opentouch", "touchanything", "native")
SPLIT_NAME = "smoke"
RECON_RATIO = 0.7
PERPLEXITY_FLOOR = 4.0


def _htdata(*args: str) -> None:
    """Run an htdata command in a child process; fail loudly with the command line."""
    cmd = [sys.executable, "-m", "htdata.cli", *args]
    print("+ htdata " + " ".join(args), flush=True)
    rc = subprocess.run(cmd).returncode
    if rc != 0:
        raise SystemExit(f"smoke: `htdata {' '.join(args)}` failed with exit code {rc}")


def ensure_raw(raw: Path, seed: int) -> None:
    if all((raw / f).is_dir() and any((raw / f).iterdir()) for f in RAW_FORMATS):
        print(f"smoke: raw corpus present at {raw}", flush=True)
        return
    _htdata("sample", str(raw), "--seed", str(seed), "--scale", "small", "--quiet", "--overwrite")


def ensure_dataset(raw: Path, dataset: Path, workers: int) -> None:
    if (dataset / "dataset.json").is_file():
        print(f"smoke: dataset present at {dataset}", flush=True)
        return
    from htdata.resources import PIPELINES_DIR

    pipes = []
    for f in RAW_FORMATS:
        pipes += ["--pipeline", f"{PIPELINES_DIR / (f + '.toml')}={raw / f}"]
    _htdata("ingest", "--workers", str(workers), "--quiet", *pipes, str(dataset))


def make_split(dataset: Path, ood_task: str, seed: int) -> None:
    _htdata("split", str(dataset), "--ood-task", ood_task, "--seed", str(seed), "--name", SPLIT_NAME, "--force")


def _toml_str(value: str) -> str:
    return json.dumps(str(value))   # a JSON string is a valid TOML basic string


def train_encoder(config: Path, encoder: str, dataset: Path, out_dir: Path, extra: list[str]):
    """Train one model with the smoke config (only the encoder differs) -> (model, train metrics)."""
    from handtouch.config import load_train_config
    from handtouch.train import load_model, train

    overrides = [f"model.encoder={_toml_str(encoder)}", f"data_root={_toml_str(dataset)}",
                 f"out_dir={_toml_str(out_dir)}", f"split={_toml_str(SPLIT_NAME)}",
                 f"train_part={_toml_str('train')}", f"eval_part={_toml_str('test')}", *extra]
    cfg = load_train_config(config, overrides)
    metrics = train(cfg)
    ckpt = Path(cfg.out_dir) / f"stage{max(cfg.stages)}.pt"    # the trainer's last stage checkpoint
    if not ckpt.is_file():
        raise SystemExit(f"smoke: training {encoder} finished without its final checkpoint {ckpt}")
    return load_model(ckpt), metrics


def codebook_perplexity(model, prep: PreparedPart) -> float:
    """exp(entropy) of code usage over every token of the prepared maps (eval mode: no restarts)."""
    if not (hasattr(model, "vq") and hasattr(model, "encode")):
        raise TypeError(f"{model.name}: no vq/encode; codebook perplexity needs a HandTouch model")
    counts = torch.zeros(model.vq.codebook_size, dtype=torch.float64)
    model.eval()
    with torch.inference_mode():
        for b in prep.frames:
            _, idx, _, _ = model.vq(model.encode(b["tactile"].float() * b["coverage"].float()))
            counts += torch.bincount(idx.flatten(), minlength=counts.numel()).double()
    p = counts[counts > 0] / counts.sum()
    return float(torch.exp(-(p * p.log()).sum()))


def learning_checks(results: dict, handtouch: str, perplexity: float) -> list[dict]:
    """The smoke run's pass/fail criteria, each with the numbers it compared."""
    ht, zeros = results[handtouch]["test"], results[ZerosModel.name]["test"]
    recon, recon_zero = ht["reconstruction"]["full"]["rmse"], zeros["reconstruction"]["full"]["rmse"]
    hit, chance = ht["retrieval"]["hit_at_1"], ht["retrieval"]["chance_hit_at_1"]
    return [
        {"check": f"stage-1 reconstruction F-RMSE <= {RECON_RATIO} x all-zeros",
         "value": recon, "limit": None if recon_zero is None else RECON_RATIO * recon_zero,
         "ok": recon is not None and recon_zero is not None and recon <= RECON_RATIO * recon_zero},
        {"check": "retrieval Hit@1 above chance", "value": hit, "limit": chance,
         "ok": hit is not None and hit > chance},
        {"check": f"codebook perplexity >= {PERPLEXITY_FLOOR}", "value": perplexity,
         "limit": PERPLEXITY_FLOOR, "ok": math.isfinite(perplexity) and perplexity >= PERPLEXITY_FLOOR},
    ]


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, torch.Tensor):
        return obj.tolist()
    if isinstance(obj, (np.generic,)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m handtouch.smoke", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("runs/smoke"), help="run folder (results, checkpoints)")
    p.add_argument("--raw", type=Path, default=None, help="raw corpus folder (default OUT/raw)")
    p.add_argument("--dataset", type=Path, default=None, help="dataset folder (default OUT/dataset)")
    p.add_argument("--config", type=Path, default=Path(__file__).resolve().parents[1] / "configs" / "smoke.toml")
    p.add_argument("--ood-task", default="palm_push", help="task held out as the ood part")
    p.add_argument("--encoders", default=",".join(ENCODERS), help="comma list; the first is HandTouch")
    p.add_argument("--max-items", type=int, default=200, help="evaluation items per part")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2, help="ingest worker processes")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="extra config override for every model (same budget for all)")
    args = p.parse_args(argv)
    args.raw = args.raw or args.out / "raw"
    args.dataset = args.dataset or args.out / "dataset"
    args.encoders = [e.strip() for e in args.encoders.split(",") if e.strip()]
    if not args.encoders or args.encoders[0] != "vit":
        p.error("--encoders must start with vit (HandTouch); the learning checks apply to it")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    torch.manual_seed(args.seed)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    ensure_raw(args.raw, args.seed)
    ensure_dataset(args.raw, args.dataset, args.workers)
    make_split(args.dataset, args.ood_task, args.seed)
    timings["data"] = time.perf_counter() - t0

    t = time.perf_counter()
    parts = {p: load_part(args.dataset, SPLIT_NAME, p) for p in ("test", "ood")}
    # decoded once, same items / masks / SSIM reference for every model
    prepared = prepare(parts, cfg=EvalConfig(max_items=args.max_items, seed=args.seed))
    timings["eval_prepare"] = time.perf_counter() - t
    models, train_metrics = {}, {}
    for enc in args.encoders:
        t = time.perf_counter()
        print(f"smoke: training encoder={enc}", flush=True)
        model, metrics = train_encoder(args.config, enc, args.dataset, args.out / "train" / enc, args.set)
        timings[f"train_{enc}"] = time.perf_counter() - t
        models[model.name] = model
        train_metrics[model.name] = metrics
    handtouch = next(iter(models))

    results = {}
    for model in [*models.values(), ZerosModel(), CopyLastModel()]:
        t = time.perf_counter()
        results[model.name] = evaluate(model, prepared)
        timings[f"eval_{model.name}"] = time.perf_counter() - t
    perplexity = codebook_perplexity(models[handtouch], prepared["test"])
    checks = learning_checks(results, handtouch, perplexity)
    timings["total"] = time.perf_counter() - t0

    meta = {"dataset": args.dataset, "split": SPLIT_NAME, "ood_task": args.ood_task, "config": args.config,
            "encoders": args.encoders, "max_items": args.max_items, "seed": args.seed,
            "handtouch": handtouch, "codebook_perplexity": perplexity, "checks": checks,
            "train_metrics": train_metrics, "seconds": timings}
    write_results(args.out, results, _jsonable(meta))
    examples = collect_examples(models[handtouch], parts["test"], count=4, seed=args.seed)
    render_predictions(examples, args.out / "predictions.png", title=f"{handtouch} on test")
    print((args.out / "results.md").read_text())
    for c in checks:
        print(f"smoke: [{'ok' if c['ok'] else 'FAILED'}] {c['check']}: value {c['value']}, limit {c['limit']}")
    print(f"smoke: {timings['total']:.0f} s total; results in {args.out}", flush=True)
    failed = [c["check"] for c in checks if not c["ok"]]
    if failed:
        print(f"smoke: HandTouch did not learn: failed {failed}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
