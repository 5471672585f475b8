"""Stage-2/3 experiments on the RGB-to-tactile track, from one finished stage-1 checkpoint.

    python -m handtouch.rgb2t_sweep --stage1 runs/smoke/train/vit/stage1.pt \
        --rgb-encoder runs/smoke/rgb_encoder/KEY/aligned.pt --dataset data/dataset \
        --out runs/rgb2t_sweep/NAME --seeds 0,1 [--set key=value ...]

e.g. the RGB prior (docs/HANDTOUCH.md, "RGB prior"): `--out runs/rgb2t_sweep/prior --set model.rgb_prior=true`
against `--out runs/rgb2t_sweep/base` (configs/smoke.toml alone keeps the paper's zeros).

For each seed: the stage-1 weights are copied into OUT/seedS/stage1.pt (the frozen RGB
encoder is --rgb-encoder's; parameters the checkpoint does not hold, or holds shaped for
another RGB encoder outside stage 1's modules, keep the fresh model's init), stages 2 and 3 of
`--config` (default: the shipped smoke config) are trained with `seed=S`, and the final model's
RGB-to-tactile F-RMSE (covered pixels, per-frame mean; HT-Bench's figure) is scored on the
split's (default `smoke`) test and ood parts next to all zeros and next to the same model fed
mis-paired RGB (shifted >= 1 s, shuffled across episodes; rgb_pretrain.partners).
Writes OUT/summary.json (atomically) and prints one line per seed and part. Stage 1 is not retrained,
so a sweep isolates what stages 2-3 do with the same tokeniser (~30 s per seed on 2 cores).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

from htdata.errors import ArgumentError
from htdata.fileio import write_json_atomic
from htdata.read import keys

from .bench.items import iterate_batches, load_part, subsample
from .bench.metrics import MapMetrics
from .config import load_train_config
from .resources import config_file
from .rgb_encoder import to_unit_float
from .rgb_pretrain import episode_fps, partners
from .train import CHECKPOINT_FORMAT, build_model, load_model, read_checkpoint, save_checkpoint, train


def seed_stage1(src: Path, cfg, dst: Path) -> None:
    """Write dst/stage1.pt: the source's stage-1 weights in a model built from cfg."""
    blob = read_checkpoint(src)
    torch.manual_seed(cfg.seed)
    model = build_model(cfg)
    # the frozen RGB encoder is --rgb-encoder's, never the checkpoint's copy
    weights = {k: v for k, v in blob["model"].items() if not k.startswith("rgb_encoder.")}
    own = model.state_dict()
    unexpected = sorted(k for k in weights if k not in own)
    if unexpected:
        raise ArgumentError(f"{src}: keys the configured model does not have: {unexpected[:8]}")
    reshaped = sorted(k for k, v in weights.items() if v.shape != own[k].shape)
    # modules stage 1 does not train (rgb_proj, fusion, ...) only hold their init: one shaped for
    # another RGB encoder is left to the fresh model's init, a stage-1 module must match
    stage1 = tuple(f"{m}." for m in cfg.stage1.trainable)
    trained = [k for k in reshaped if k.startswith(stage1)]
    if trained:
        raise ArgumentError(f"{src}: stage-1 weights shaped unlike the configured model's (was stage 1 "
                            f"trained with another model config?): {trained[:8]}")
    weights = {k: v for k, v in weights.items() if k not in reshaped}
    missing, _ = model.load_state_dict(weights, strict=False)
    missing = [k for k in missing if not k.startswith("rgb_encoder.")]
    dst.mkdir(parents=True, exist_ok=True)
    save_checkpoint(dst / "stage1.pt", {**blob, "model": model.state_dict(), "new_keys": missing,
                                        "format": CHECKPOINT_FORMAT,
                                        "model_config": dataclasses.asdict(cfg.model),
                                        "rgb_encoder": {"spec": model.rgb_encoder.info.spec,
                                                        "sha256": model.rgb_encoder.info.sha256}})


def load_frames(dataset: str, split: str, part: str, max_items: int, seed: int = 0) -> dict:
    ds = load_part(dataset, split, part).frames
    out: dict[str, list] = {}
    for b in iterate_batches(ds, subsample(len(ds), max_items, seed), 32):
        for k in (keys.TACTILE, keys.COVERAGE, keys.RGB, keys.HAND, keys.EPISODE, keys.FRAME):
            out.setdefault(k, []).append(b[k])
    return {k: torch.cat(v) for k, v in out.items()}


@torch.inference_mode()
def score(model, frames: dict, fps: np.ndarray, seed: int = 0) -> dict:
    """RGB-to-tactile F-RMSE (covered) aligned / zeros / shifted / shuffled on the same frames."""
    ep, fr = frames[keys.EPISODE].reshape(-1).numpy(), frames[keys.FRAME].reshape(-1).numpy()
    src = {p: partners(ep, fr, fps[ep], p, 1.0, seed) for p in ("aligned", "shifted", "shuffled")}
    metrics = {p: MapMetrics() for p in (*src, "zeros", "probe")}
    backbone = model.rgb_encoder.backbone
    probe = callable(getattr(backbone, "predict", None))   # TactileGridRGB: its own coarse map, upsampled
    tac, cov = frames[keys.TACTILE].float(), (frames[keys.COVERAGE].float() > 0.5).float()
    hand = frames[keys.HAND].reshape(-1).long()
    for s in range(0, len(ep), 32):
        i = np.arange(s, min(s + 32, len(ep)))
        t, c, h = tac[i], cov[i], hand[i]
        metrics["zeros"].update(torch.zeros_like(t), t, c)
        if probe:
            coarse = backbone.predict(backbone(to_unit_float(frames[keys.RGB][i])), h)
            metrics["probe"].update(torch.nn.functional.interpolate(coarse, size=t.shape[-2:]) * c, t, c)
        for p, j in src.items():
            j = np.where(j[i] >= 0, j[i], i)      # items without a partner keep their own frame
            metrics[p].update(model.rgb_to_tactile(frames[keys.RGB][j], c, h), t, c)
    return {p: m.result()["rmse"] for p, m in metrics.items() if probe or p != "probe"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m handtouch.rgb2t_sweep", description=__doc__.splitlines()[0],
                                 epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, default=None, help="trainer config (default: the shipped smoke config)")
    ap.add_argument("--stage1", required=True, type=Path, help="a finished stage-1 checkpoint (stage1.pt)")
    ap.add_argument("--rgb-encoder", required=True, help="frozen RGB encoder spec (file or random:SEED)")
    ap.add_argument("--dataset", required=True, help="committed dataset with the split")
    ap.add_argument("--split", default="smoke", help="split with test and ood parts (default %(default)s)")
    ap.add_argument("--out", required=True, type=Path, help="sweep folder (one seedS/ per seed, summary.json)")
    ap.add_argument("--seeds", default="0,1", help="comma list of training seeds (default %(default)s)")
    ap.add_argument("--max-items", type=int, default=200, help="scored items per part (default %(default)s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    args = ap.parse_args(argv)
    args.config = args.config or config_file("smoke")
    torch.set_num_threads(1)
    fps = episode_fps(args.dataset)
    parts = {p: load_frames(args.dataset, args.split, p, args.max_items) for p in ("test", "ood")}
    summary = {"args": {k: str(v) for k, v in vars(args).items()}, "seeds": {}}
    for seed in [int(s) for s in args.seeds.split(",")]:
        out = args.out / f"seed{seed}"
        sets = [f'data_root="{args.dataset}"', f'split="{args.split}"', f'out_dir="{out}"',
                f'rgb_encoder="{args.rgb_encoder}"', f"seed={seed}", "stages=[2, 3]", *args.set]
        cfg = load_train_config(Path(args.config), sets)
        if not (out / "stage1.pt").is_file():
            seed_stage1(args.stage1, cfg, out)
        train(cfg, on_record=lambda r: None)
        summary["seeds"][seed] = {}
        for stage in cfg.stages:
            model = load_model(out / f"stage{stage}.pt")
            res = summary["seeds"][seed][f"stage{stage}"] = {p: score(model, f, fps) for p, f in parts.items()}
            for p, r in res.items():
                print(f"seed {seed} after stage {stage} {p}: " + " ".join(f"{k} {v:.4f}" for k, v in r.items()),
                      flush=True)
    write_json_atomic(args.out / "summary.json", summary, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
