"""HandTouch trainer: stage 1 (reconstruct) -> 2 (masked + RGB) -> 3 (predict t_T).

The loop is generic: what each stage reads, prepares, computes and trains is its
`handtouch.stages.Stage` object.

    python -m handtouch.train --config configs/smoke.toml [--set key=value ...]
    torchrun --nproc_per_node 2 -m handtouch.train --config ...      (DDP)

Each stage writes OUT/stageN.pt (model, optimizer, step, RNG states); a re-run
continues an unfinished stage from its checkpoint and skips finished ones.
Losses and throughput go to OUT/log.jsonl and to stdout (the CLI; `train()` logs them
through `logging` unless given `on_record`); OUT/metrics.json holds the
final losses per stage, codebook perplexity / usage, recon RMSE on a held-out
batch and steps/s. Python API: `train(cfg) -> metrics`, `load_model(path)`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from htdata.errors import ArgumentError, ConfigError
from htdata.fileio import write_json_atomic
from htdata.read import keys
from htdata.read.itemoptions import ItemOptions
from htdata.read.torchdata import ItemConstants, TactileFrameDataset, TactileWindowDataset

from .checkpoint import CHECKPOINT_FORMAT, read_checkpoint, rng_state, save_checkpoint, set_rng_state
from .config import WINDOW, TrainConfig, load_train_config, model_config_from_dict
from .distributed import DistEnv, StepBatchSampler, barrier, init_distributed, shutdown, torch_threads, wrap
from .model import HandTouch, covered, masked_mse
from .progress import with_steps_after
from .resources import config_file
from .rgb_encoder import load_rgb_encoder
from .stages import FRAMES, WINDOWS, Stage, StageLoss, build_stages
from .steploop import StageRun, make_optimizer, to_device, train_steps

log = logging.getLogger("handtouch.train")


@dataclass
class TrainData:
    frames: Dataset            # stages.FRAMES items (TactileFrameDataset keys)
    windows: Dataset | None    # stages.WINDOWS items (TactileWindowDataset keys); None if no stage reads them
    eval_frames: Dataset       # source of the held-out batch
    eval_source: str           # what eval_frames is, for metrics.json
    tactile_frames: Dataset | None = None   # frames without RGB, for stages that read none (Stage.reads_rgb)
    constants: ItemConstants | None = None  # per-layout constants of constants="once" items (wrapped datasets)

    def items(self, kind: str, rgb: bool = True) -> Dataset | None:
        """The dataset a stage reads (Stage.data: stages.FRAMES or stages.WINDOWS; rgb: Stage.reads_rgb)."""
        if kind not in (FRAMES, WINDOWS):
            raise ValueError(f"unknown stage data kind {kind!r}; known: {FRAMES!r}, {WINDOWS!r}")
        if kind == FRAMES and not rgb and self.tactile_frames is not None:
            return self.tactile_frames
        return self.frames if kind == FRAMES else self.windows


def load_data(cfg: TrainConfig) -> TrainData:
    """The committed dataset at cfg.data_root through htdata.read.torchdata.

    Training frames carry per-layout constants once (constants="once": expanded on the
    device); stage 1 reads frames without RGB (no JPEG decoded, ~1/3 fewer bytes moved).
    """

    split = cfg.split or None
    train_part = cfg.train_part if split else None
    once = ItemOptions(split=split, part=train_part, constants="once")
    frames = TactileFrameDataset(cfg.data_root, options=once)
    tactile = TactileFrameDataset(cfg.data_root, options=once.replace(members=(keys.TACTILE,)))
    windows = (TactileWindowDataset(cfg.data_root, window=WINDOW, options=ItemOptions(split=split, part=train_part))
               if any(s.data == WINDOWS for s in build_stages(cfg)) else None)
    if split:
        eval_frames = TactileFrameDataset(cfg.data_root, options=ItemOptions(split=split, part=cfg.eval_part))
        source = f"part {cfg.eval_part!r} of split {split!r}"
    else:
        eval_frames = TactileFrameDataset(cfg.data_root)   # items with their constants: a batch as-is
        source = "training data (no split configured: not held out)"
    return TrainData(frames, windows, eval_frames, source, tactile, frames.constants())


def build_model(cfg: TrainConfig) -> HandTouch:
    return HandTouch(cfg.model, load_rgb_encoder(cfg.rgb_encoder))


def load_model(checkpoint_path: str | Path, device: str = "cpu") -> HandTouch:
    """A trained HandTouch in eval mode, from any OUT/stageN.pt."""
    path = Path(checkpoint_path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    blob = read_checkpoint(path)
    rgb = load_rgb_encoder(blob["rgb_encoder"]["spec"])
    if rgb.info.sha256 != blob["rgb_encoder"]["sha256"]:
        raise ArgumentError(f"{path}: RGB encoder {rgb.info.spec} has sha256 {rgb.info.sha256}, "
                            f"the checkpoint was trained with {blob['rgb_encoder']['sha256']}")
    model = HandTouch(model_config_from_dict(blob["model_config"]), rgb)
    model.load_state_dict(blob["model"])
    return model.to(device).eval()


# ---- one stage -----------------------------------------------------------------------
class JsonlLog:
    """Training records: appended to OUT/log.jsonl (when `path` is set), then handed to
    `emit` if given (the CLI prints them), else logged at INFO on "handtouch.train"."""

    def __init__(self, path: Path | None, emit: Callable[[dict], None] | None = None):
        self.path = path
        self.emit = emit

    def write(self, record: dict) -> None:
        line = json.dumps(record)
        if self.path is not None:
            with self.path.open("a") as f:
                f.write(line + "\n")
        if self.emit is not None:
            self.emit(record)
        else:
            log.info("%s", line)


def _stage_loader(stage: Stage, cfg: TrainConfig, data: TrainData, env: DistEnv, start: int) -> DataLoader:
    """Batches of the stage's dataset kind for steps [start, steps) of this rank."""
    n = stage.number
    dataset = data.items(stage.data, stage.reads_rgb)
    if dataset is None:
        raise ValueError(f"stage {n} needs {stage.data} data (TrainData.{stage.data} is None)")
    try:
        sampler = StepBatchSampler(len(dataset), cfg.batch_size, cfg.seed + n, start, stage.cfg.steps,
                                   env.rank, env.world_size)
    except ConfigError as e:   # too few samples for one batch; a bad call stays a plain ValueError
        raise ConfigError(f"stage {n} ({stage.items} items from {cfg.data_root}): {e}") from None
    return DataLoader(dataset, batch_sampler=sampler, num_workers=cfg.workers,
                      generator=torch.Generator().manual_seed(cfg.seed),  # keep global RNG untouched
                      persistent_workers=False, pin_memory=env.device.type == "cuda",
                      prefetch_factor=cfg.prefetch if cfg.workers else None)


def run_stage(stage: Stage, model: HandTouch, cfg: TrainConfig, data: TrainData, env: DistEnv,
              out: Path, logger: JsonlLog, heldout: dict | None = None,
              on_progress: Callable[[dict], None] | None = None) -> dict:
    """Train one stage (resuming / skipping from OUT/stageN.pt); returns the stage summary."""
    n, steps = stage.number, stage.cfg.steps
    ckpt_path = out / f"stage{n}.pt"
    state = read_checkpoint(ckpt_path) if ckpt_path.is_file() else None
    if state is not None and state["done"]:
        model.load_state_dict(state["model"])
        set_rng_state(state["rng"])   # later stages start from the same RNG as an uninterrupted run
        logger.write({"event": "stage_skipped", "stage": n, "reason": f"{ckpt_path} is finished"})
        return state["summary"]

    stage.configure(model)
    model.train()
    params = [p for p in model.parameters() if p.requires_grad]
    opt = make_optimizer(params, stage.cfg.lr, stage.cfg.weight_decay, env.device)
    start = 0
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start = state["step"]
        logger.write({"event": "stage_resumed", "stage": n, "step": start})
    loader = _stage_loader(stage, cfg, data, env, start)
    if state is not None:
        set_rng_state(state["rng"])

    def checkpoint(step: int, done: bool = False, summary: dict | None = None) -> None:
        if env.is_main:
            save_checkpoint(ckpt_path, {
                "format": CHECKPOINT_FORMAT, "stage": n, "step": step, "done": done,
                "model": model.state_dict(), "optimizer": opt.state_dict(), "rng": rng_state(),
                "model_config": dataclasses.asdict(cfg.model),
                "rgb_encoder": {"spec": model.rgb_encoder.info.spec, "sha256": model.rgb_encoder.info.sha256},
                "summary": summary or {}})
        barrier(env)

    step_loss = wrap(StageLoss(stage, model), env)
    if cfg.compile:
        step_loss = torch.compile(step_loss)
    run = StageRun(stage, step_loss, opt, params, cfg, env, logger.write, _constants(data, loader.dataset, env.device),
                   progress=on_progress if env.is_main else None)
    t_start = time.perf_counter()
    last, step = train_steps(run, loader, start, checkpoint)
    seconds = time.perf_counter() - t_start
    ran = steps - start
    summary = {"steps": steps, "resumed_from": start, "final": last, "seconds": seconds, "timing": run.times.as_dict(),
               "steps_per_s": ran / max(seconds, 1e-9),
               "samples_per_s": ran * cfg.batch_size * env.world_size / max(seconds, 1e-9)}
    if ran and step + 1 != steps:
        raise RuntimeError(f"stage {n}: data loader stopped at step {step + 1} of {steps}")
    if heldout is not None:   # how each stage leaves reconstruction (stage 3 fine-tunes vq + decoder)
        summary["heldout"] = evaluate_heldout(model, heldout, env.device)
        model.train()
    checkpoint(steps, True, summary)
    return summary


def _constants(data: TrainData, dataset: Dataset, device: torch.device) -> ItemConstants | None:
    """Per-layout constants on the device, once per stage: TrainData's, else the dataset's (None: items carry them)."""
    if data.constants is not None:
        return data.constants.to(device)
    constants = getattr(dataset, "constants", None)
    return constants().to(device) if constants is not None else None


# ---- evaluation on the held-out batch -------------------------------------------------
def heldout_batch(dataset: Dataset, size: int, source: str = "held-out data") -> dict:
    """`size` evenly spaced items (deterministic) collated into a batch."""
    n = len(dataset)
    if n == 0:
        raise ArgumentError(f"{source} has no items: cannot build the held-out batch")
    idx = np.unique(np.linspace(0, n - 1, num=min(size, n)).round().astype(int))
    return torch.utils.data.default_collate([dataset[int(i)] for i in idx])


@torch.no_grad()
def evaluate_heldout(model: HandTouch, batch: dict, device: torch.device) -> dict:
    """Reconstruction / codebook numbers on the held-out batch (pooled RMSE over covered
    pixels, next to the all-zeros predictor's on the same batch).

    Runs on rank 0 only, so it must issue no collective: the model is put in eval mode,
    where the VQ neither all-reduces usage nor restarts (and broadcasts) codes.
    """
    model.eval()
    batch = to_device(batch, device)
    cov = batch[keys.COVERAGE]
    target = covered(batch[keys.TACTILE], cov)
    pred, _, _, stats = model.quantise_decode(model.encode(target), cov)
    out = {"recon_rmse": math.sqrt(float(masked_mse(pred, target, cov))),
           "zeros_rmse": math.sqrt(float(masked_mse(torch.zeros_like(target), target, cov))),
           "codebook": {"perplexity": float(stats["perplexity"]), "batch_usage": float(stats["usage"]),
                        "active_fraction": float((model.vq.usage >= model.vq.dead_threshold).float().mean()),
                        "size": model.vq.codebook_size},
           "heldout_items": int(target.shape[0])}
    rgb_pred = model.rgb_to_tactile(batch[keys.RGB], cov, batch[keys.HAND])
    out["rgb_to_tactile_rmse"] = math.sqrt(float(masked_mse(rgb_pred, target, cov)))
    return out


# ---- driver --------------------------------------------------------------------------
def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def train(cfg: TrainConfig, data: TrainData | None = None,
          on_record: Callable[[dict], None] | None = None,
          on_progress: Callable[[dict], None] | None = None) -> dict:
    """Run the configured stages; returns (and on rank 0 writes) OUT/metrics.json's content.

    Every log record goes to OUT/log.jsonl and to `on_record` (default: logging at INFO);
    `on_progress` gets every step's position and rate (handtouch.progress.Rate; rank 0).
    """
    cfg.validate()
    with torch_threads(cfg.threads):      # cfg.threads is this training run's budget only
        return _train(cfg, data, on_record, on_progress)


def _train(cfg: TrainConfig, data: TrainData | None, on_record: Callable[[dict], None] | None,
           on_progress: Callable[[dict], None] | None = None) -> dict:
    env = init_distributed(cfg.device)
    try:
        cfg.check_codebook_load(env.world_size)
        out = Path(cfg.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        logger = JsonlLog(out / "log.jsonl" if env.is_main else None, on_record)
        _seed_everything(cfg.seed)   # same on every rank: identical initial weights
        data = data or load_data(cfg)
        model = build_model(cfg).to(env.device)
        first = cfg.stages[0]
        if first > 1:
            prev = out / f"stage{first - 1}.pt"
            if not prev.is_file():
                raise FileNotFoundError(f"stages start at {first} but {prev} does not exist")
            model.load_state_dict(read_checkpoint(prev)["model"])
        logger.write({"event": "start", "model": model.name, "world_size": env.world_size,
                      "device": str(env.device), "bf16": cfg.bf16, "rgb_encoder": model.rgb_encoder.info.spec,
                      "rgb_encoder_sha256": model.rgb_encoder.info.sha256,
                      "train_items": len(data.frames), "window_items": len(data.windows or [])})
        heldout = (heldout_batch(data.eval_frames, cfg.eval_batch_size, data.eval_source)
                   if env.is_main else None)
        summaries = {}
        stages = build_stages(cfg)
        for k, stage in enumerate(stages):
            progress = with_steps_after(on_progress, sum(s.cfg.steps for s in stages[k + 1:]))   # run-wide ETA
            summaries[str(stage.number)] = run_stage(stage, model, cfg, data, env, out, logger, heldout, progress)
        metrics = {"model": model.name, "encoder": cfg.model.encoder, "world_size": env.world_size,
                   "device": str(env.device), "rgb_encoder": dataclasses.asdict(model.rgb_encoder.info),
                   "stages": summaries, "heldout_source": data.eval_source}
        ran = [s for s in summaries.values() if s.get("seconds", 0) > 0]
        total_steps = sum(s["steps"] - s.get("resumed_from", 0) for s in ran)
        metrics["steps_per_s"] = total_steps / max(sum(s["seconds"] for s in ran), 1e-9) if ran else 0.0
        if env.is_main:
            metrics.update(evaluate_heldout(model, heldout, env.device))
            write_json_atomic(out / "metrics.json", metrics)
            logger.write({"event": "done", "metrics": str(out / "metrics.json"),
                          "recon_rmse": metrics["recon_rmse"]})
        barrier(env)
        return metrics
    finally:
        shutdown(env)


def _config_path(arg: str) -> Path:
    """A path to a TOML file, else a bare name resolved among the shipped configs."""
    path = Path(arg)
    if path.is_file() or path.name != arg:
        return path
    return config_file(arg)


def _print_record(record: dict) -> None:
    print(json.dumps(record), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m handtouch.train", description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True,
                        help="TOML file, or the name of a shipped config (smoke, full: handtouch.resources)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config key, e.g. --set model.dim=64 --set stage1.steps=10")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        cfg = load_train_config(_config_path(args.config), args.set)
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    train(cfg, on_record=_print_record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
