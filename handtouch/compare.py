"""`python -m handtouch.compare --config configs/compare_smoke.toml`: the paper's comparison.

Trains HandTouch, the four encoder baselines, the three ablations and the three design
choices of this implementation (`ROWS`) on the same split with the same config and budget
(each row changes only its `overrides`), scores each on HT-Bench (retrieval, inpainting,
RGB-to-tactile, prediction; plus reconstruction) next to the all-zeros and copy-last
references, and writes OUT/compare.json and OUT/compare.md (the paper's table: one row per
method, the tracks as columns, one table per part).

Data: the smoke's (handtouch.smokedata: sample -> ingest -> split `smoke` with `cup_grasp` and
`palm_push` as OOD), reused when present; `--split NAME` takes an existing split of `--dataset` as is.
RGB encoder: the smoke's pretrained aligned probe (handtouch.rgb_pretrain, cached under
--rgb-cache, shared with the smoke), or `--rgb-encoder config` for the config's own
`rgb_encoder` (a file with real weights, or random:SEED in tests).

Each row trains into OUT/train/KEY-HASH (HASH of its resolved config): a re-run with the
same config reuses the finished checkpoints, a changed config trains afresh. A row whose
resolved config equals HandTouch's (e.g. a design row already on in the base config) is
reported as such and not trained twice.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from handtouch import smokedata
from handtouch.bench.evaluate import evaluate
from handtouch.bench.items import EvalConfig, prepare
from handtouch.bench.references import CopyLastModel, ZerosModel
from handtouch.bench.report import COLUMNS, FULL_COLUMNS, markdown_table
from handtouch.config import load_train_config
from handtouch.progress import PhaseTimer
from handtouch.rgb_pretrain import RGBPretrainConfig, ensure_probes
from handtouch.smoke import jsonable
from handtouch.smokechecks import codebook_perplexity as perplexity  # the smoke check's own measure
from handtouch.train import load_model, train
from htdata.fileio import write_json_atomic, write_text_atomic

OURS, BASELINE, ABLATION, DESIGN = "ours", "baseline", "ablation", "design choice"


@dataclass(frozen=True)
class Row:
    key: str                       # folder-safe id (--rows)
    label: str                     # the table's row label
    group: str                     # OURS | BASELINE | ABLATION | DESIGN
    overrides: tuple[str, ...]     # config overrides on top of the base config (--set syntax)
    definition: str                # what the row is, for the report


ROWS = (
    Row("handtouch", "HandTouch (ViT + VQ)", OURS, (), "the base config"),
    Row("cnn", "CNN", BASELINE, ('model.encoder="cnn"',), "conv encoder (stride 16) in HandTouch's place"),
    Row("resnet18", "ResNet-18", BASELINE, ('model.encoder="resnet18"',),
        "ResNet-18-layout encoder (stride 32) in HandTouch's place"),
    Row("vqvae", "VQ-VAE", BASELINE, ('model.encoder="vqvae"',),
        "conv VQ-VAE tokeniser: conv encoder -> VQ -> conv decoder, no attention in the autoencoder"),
    Row("vit_plain", "ViT", BASELINE, ('model.encoder="vit_plain"',),
        "plain ViT regressor: ViT encoder, no codebook, linear per-patch pixel head"),
    Row("no_drop", "w/o drop", ABLATION, ("masking.curriculum=false",),
        "no masking curriculum: P_full fixed at its midpoint"),
    Row("no_codebook", "w/o codebook", ABLATION, ("model.codebook=false",), "continuous latent, VQ bypassed"),
    Row("no_vision", "w/o vision", ABLATION, ("model.vision=false",),
        "stages 2-3 attend to the hand token only, never to RGB"),
    Row("stage3_replay", "stage 3 + replay + VQ terms", DESIGN, ("loss.stage3_replay=1.0", "loss.stage3_vq=true"),
        "stage 3 adds t_T's reconstruction and the VQ terms to the paper's next-frame MSE"),
    Row("two_channel", "2-channel input", DESIGN, ("model.mask_channel=true",),
        "encoder also sees the hidden-pixel mask as a second channel (the paper: the masked map only)"),
    Row("rgb_prior", "RGB prior", DESIGN, ("model.rgb_prior=true",),
        "hidden pixels start from the frozen RGB probe's coarse contact map, not 0 (the smoke's choice)"),
)
ROW_KEYS = tuple(r.key for r in ROWS)


def _hash(cfg) -> str:
    """Hash of a resolved TrainConfig without its out_dir (the row's identity on disk)."""
    doc = dataclasses.asdict(cfg)
    doc.pop("out_dir")
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:10]


def resolve_rows(config: Path, sets: list[str], rows: list[Row], out: Path) -> list[tuple[Row, object, str]]:
    """-> [(row, its TrainConfig, the key of the row it duplicates or "")]; the user's --set
    overrides come last. Each config's out_dir is OUT/train/KEY-HASH."""
    resolved, seen = [], {}
    for row in rows:
        cfg = load_train_config(config, [*sets, *row.overrides])
        digest = _hash(cfg)
        cfg.out_dir = str(out / "train" / f"{row.key}-{digest}")
        resolved.append((row, cfg, seen.get(digest, "")))
        seen.setdefault(digest, row.key)
    return resolved


def codebook_perplexity(model, prepared) -> float | None:
    """exp(entropy) of code usage over every token of the first part's maps; None without a codebook."""

    if not model.cfg.quantised:
        return None
    return perplexity(model, next(iter(prepared.values())))


def train_and_score(cfg, prepared) -> dict:
    """Train one row (or reuse its finished checkpoints) and score it on every prepared part."""

    metrics = train(cfg)
    model = load_model(Path(cfg.out_dir) / f"stage{max(cfg.stages)}.pt")
    seconds = sum(s.get("seconds", 0.0) for s in metrics["stages"].values())
    return {"results": evaluate(model, prepared, parts=tuple(prepared)),
            "perplexity": codebook_perplexity(model, prepared), "train_seconds": seconds,
            "steps": {k: s["steps"] for k, s in metrics["stages"].items()}, "out_dir": cfg.out_dir,
            "model": model.name}


def compare(config: Path, sets: list[str], prepared: dict, out: Path, rows: list[Row] = ROWS,
            log=print) -> dict:
    """Train and score every row and the references -> the compare.json document (also written,
    with compare.md, to OUT)."""
    out.mkdir(parents=True, exist_ok=True)
    doc = {"config": str(config), "sets": list(sets), "parts": list(prepared), "rows": [], "references": {}}
    scored: dict[str, dict] = {}
    for row, cfg, same_as in resolve_rows(config, sets, rows, out):
        entry = {"key": row.key, "label": row.label, "group": row.group, "overrides": list(row.overrides),
                 "definition": row.definition, "same_as": same_as}
        if same_as:
            log(f"compare: {row.key} has the same resolved config as {same_as}: not trained again")
            entry.update(scored[same_as])
        else:
            log(f"compare: training {row.key} ({' '.join(row.overrides) or 'base config'}) -> {cfg.out_dir}")
            scored[row.key] = train_and_score(cfg, prepared)
            entry.update(scored[row.key])
        doc["rows"].append(entry)
    with torch.inference_mode():
        for ref in (ZerosModel(), CopyLastModel()):
            doc["references"][ref.name] = evaluate(ref, prepared, parts=tuple(prepared))
    write_comparison(out, doc)
    return doc


def write_comparison(out: Path, doc: dict) -> None:
    write_json_atomic(out / "compare.json", jsonable(doc))
    write_text_atomic(out / "compare.md", comparison_markdown(doc))


def _fmt(v) -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3f}"


def comparison_markdown(doc: dict) -> str:
    """The paper's table per part (rows in ROWS order, then the references), the whole-canvas
    figures, and a diagnostics table (codebook perplexity, training time, definitions)."""
    results = {r["label"]: r["results"] for r in doc["rows"]}
    results.update(doc["references"])
    parts = doc["parts"]
    text = ["# HandTouch comparison (HT-Bench)\n",
            f"Config `{doc['config']}` {' '.join('--set ' + s for s in doc['sets'])}; every row trains with the "
            "same config, budget and split; a row changes only its overrides (below). Covered-pixel "
            "metrics; RMSE / cIoU are per-frame means.\n"]
    for part in parts:
        one = {name: {part: by_part[part]} for name, by_part in results.items() if part in by_part}
        text += [f"## {part}: covered pixels\n", markdown_table(one, COLUMNS)]
    first = parts[0]
    text += [f"## {first}: whole canvas (f_full, h_full)\n",
             markdown_table({n: {first: p[first]} for n, p in results.items() if first in p}, FULL_COLUMNS)]
    rows = ["| Row | Group | Overrides | Codebook perplexity | Recon F-RMSE | Train s | Definition |",
            "|---|---|---|---:|---:|---:|---|"]
    for r in doc["rows"]:
        recon = r["results"][first]["reconstruction"]["f_covered"]["rmse"]
        over = " ".join(f"`{o}`" for o in r["overrides"]) or "–"
        same = f" (same config as {r['same_as']})" if r["same_as"] else ""
        rows.append(f"| {r['label']} | {r['group']} | {over} | {_fmt(r['perplexity'])} | {_fmt(recon)} | "
                    f"{r['train_seconds']:.0f} | {r['definition']}{same} |")
    text += [f"## Diagnostics ({first})\n",
             "Codebook perplexity: exp(entropy) of code usage over every token of the part's maps "
             "(final model; – = no codebook). Recon: stage-1 autoencoding through the final model.\n",
             "\n".join(rows) + "\n"]
    if doc.get("seconds"):
        text.append(f"Wall time: {doc['seconds'].get('total', 0):.0f} s ("
                    + ", ".join(f"{k} {v:.0f} s" for k, v in doc["seconds"].items() if k != "total") + ").\n")
    return "\n".join(text)


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m handtouch.compare", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, required=True, help="base trainer config (e.g. configs/compare_smoke.toml)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override for every row")
    p.add_argument("--out", type=Path, default=Path("runs/compare"), help="run folder")
    p.add_argument("--raw", type=Path, default=Path("runs/smoke/raw"), help="raw sample corpus (the smoke's)")
    p.add_argument("--dataset", type=Path, default=Path("runs/smoke/dataset"), help="dataset (the smoke's)")
    p.add_argument("--split", default="", help="use this existing split as is (default: the smoke's split)")
    p.add_argument("--parts", default="test,ood", help="comma list of split parts to score")
    p.add_argument("--rows", default=",".join(ROW_KEYS), help=f"comma list of {', '.join(ROW_KEYS)}")
    p.add_argument("--rgb-encoder", choices=("pretrain", "config"), default="pretrain",
                   help="pretrain: the smoke's aligned RGB probe; config: the config's rgb_encoder")
    p.add_argument("--rgb-cache", type=Path, default=Path("runs/smoke/rgb_encoder"), help="RGB probe cache")
    p.add_argument("--max-items", type=int, default=100, help="evaluation items per part")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--ood-task", action="append", default=None, dest="ood_tasks", metavar="TASK",
                   help=f"held-out task(s) of the split (default: the smoke's, {smokedata.OOD_TASK} and "
                        f"{smokedata.STRESS_TASK})")
    args = p.parse_args(argv)
    keys = [k.strip() for k in args.rows.split(",") if k.strip()]
    unknown = sorted(set(keys) - set(ROW_KEYS))
    if unknown or not keys:
        p.error(f"--rows: unknown {unknown}; known: {list(ROW_KEYS)}")
    args.rows = [r for r in ROWS if r.key in keys]
    args.parts = [s.strip() for s in args.parts.split(",") if s.strip()]
    args.ood_tasks = args.ood_tasks or [smokedata.OOD_TASK, smokedata.STRESS_TASK]
    return args


def main(argv=None) -> int:

    args = parse_args(argv)
    timer = PhaseTimer()
    torch.manual_seed(args.seed)
    threads = load_train_config(args.config, args.set).threads
    if threads:
        torch.set_num_threads(threads)   # evaluation under the training budget too (see handtouch.smoke)
    split = args.split
    if not split:
        timer.run("data", smokedata.ensure_raw, args.raw, args.seed)
        timer.run("data", smokedata.ensure_dataset, args.raw, args.dataset, 2)
        timer.run("data", smokedata.make_split, args.dataset, args.ood_tasks, args.seed)
        split = smokedata.SPLIT_NAME
    sets = [f"data_root={smokedata.toml_str(args.dataset)}", f"split={smokedata.toml_str(split)}"]
    if args.rgb_encoder == "pretrain":
        probe = timer.run("rgb_pretrain", ensure_probes, args.dataset, split, args.rgb_cache,
                          RGBPretrainConfig(seed=args.seed), pairings=("aligned",))["aligned"]
        sets.append(f"rgb_encoder={smokedata.toml_str(probe.resolve())}")
    prepared = timer.run("eval_prepare", prepare, str(args.dataset), split, args.parts,
                         EvalConfig(max_items=args.max_items, seed=args.seed))
    doc = timer.run("train_and_score", compare, args.config, [*sets, *args.set], prepared, args.out, args.rows)
    doc["seconds"] = timer.total()
    write_comparison(args.out, doc)
    print((args.out / "compare.md").read_text())
    print(f"compare: {doc['seconds']['total']:.0f} s for {len(args.rows)} rows; {args.out / 'compare.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
