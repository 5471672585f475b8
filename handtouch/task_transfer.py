"""Which held-out tasks can RGB predict touch for? Leave-one-task-out RGB probes.

    python -m handtouch.task_transfer --dataset data/dataset --out runs/task_transfer

The smoke's OOD part is one held-out task, so its RGB-to-tactile verdict says how well
the frozen RGB probe (rgb_pretrain.py) transfers to THAT task. This command asks it of
every task: for each task T, a probe of the smoke's config is trained on the other tasks'
train episodes and scored (covered-cell MSE relative to all zeros, the control's figure)

  seen    on the other tasks' test episodes (htdata.store.splitrule's rule: 10% of each task's
          episodes, seeded), the in-distribution level of the same probe, and
  held    on every decoded frame of T, which no training item came from.

A ratio below 1 on `held` means the probe predicts T's touch better than all zeros. The
frames are decoded once (a seeded subsample of the whole dataset) and partitioned in
memory: no split is written and the dataset is not touched. `--controls` also trains the
smoke's misalignment controls (RGB shifted >= 1 s, RGB of another episode) on each split,
which is how rgb_pretrain.REQUIRED_CONTROLS was chosen. Writes OUT/task_transfer.json and
OUT/task_transfer.md; ~10 s per task on 2 CPU cores on the sample data (x3 with --controls).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import torch

from htdata.fileio import write_json_atomic, write_text_atomic
from htdata.read.metadata import DatasetMetadata
from htdata.store.splitrule import assign_episodes

from .config import parse_override
from .probeitems import ProbeItems, load_items
from .rgb_pretrain import PAIRINGS, RGBPretrainConfig, probe_score, save_probe, train_probe


def subset(items: ProbeItems, mask: np.ndarray) -> ProbeItems:
    """The items where `mask` (N,) bool is true, every field alike."""
    idx = torch.from_numpy(np.flatnonzero(mask))
    return ProbeItems(items.rgb[idx], items.cells[idx], items.weight[idx], items.hand[idx],
                      items.episode[mask], items.frame[mask], items.fps[mask])


def item_parts(episodes: list[dict], item_episode: np.ndarray, held_task: str, test_ratio: float,
               seed: int) -> np.ndarray:
    """(N,) part of each item ("train", "test" or "ood") with `held_task` held out whole."""
    assignment, _ = assign_episodes(episodes, [held_task], test_ratio, seed)
    by_position = np.array([assignment[ep["episode_id"]] for ep in episodes])
    return by_position[item_episode]


def transfer_table(dataset, cfg: RGBPretrainConfig, tasks: list[str] | None = None, test_ratio: float = 0.1, *,
                   probe_dir: Path, progress=print, controls: bool = False, split_seed: int = 0) -> dict:
    """{"tasks": {task: {"seen": score, "held": score, "train_items": n}}} for each task (default: all),
    the probes saved as probe_dir/TASK[-PAIRING].pt. controls: also train the misalignment controls
    (rgb_pretrain.PAIRINGS) on the same train items and score each on the seen test items under
    its own pairing -> row["controls"][pairing], the smoke's control on this split."""
    episodes = DatasetMetadata(dataset).episodes
    known = sorted({ep["task"] for ep in episodes})
    tasks = tasks or known
    unknown = sorted(set(tasks) - set(known))
    if unknown:
        raise SystemExit(f"task_transfer: {dataset} has no task {unknown} (tasks: {known})")
    if len(known) < 2:
        raise SystemExit(f"task_transfer: {dataset} has {len(known)} task; holding one out needs at least 2")
    items = load_items(dataset, None, None, cfg)
    out = {}
    for task in tasks:
        part = item_parts(episodes, items.episode, task, test_ratio, split_seed)
        train = subset(items, part == "train")
        seen = subset(items, part == "test")
        paths = {}
        for pairing in PAIRINGS if controls else ("aligned",):
            paths[pairing] = Path(probe_dir) / (f"{task}.pt" if pairing == "aligned" else f"{task}-{pairing}.pt")
            save_probe(train_probe(train, pairing, cfg), paths[pairing],
                       {"pairing": pairing, "dataset": str(dataset), "held_task": task,
                        "config": dataclasses.asdict(cfg)})
        row = {"train_items": int(len(train.hand)),
               "seen": probe_score(paths["aligned"], seen, "aligned"),
               "held": probe_score(paths["aligned"], subset(items, part == "ood"), "aligned")}
        if controls:
            row["controls"] = {p: probe_score(paths[p], seen, p, cfg.shift_seconds, cfg.seed) for p in PAIRINGS[1:]}
        out[task] = row
        progress(f"task_transfer: {task}: seen {_fmt(row['seen']['ratio'])}, held {_fmt(row['held']['ratio'])}"
                 + "".join(f", {p} {_fmt(c['ratio'])}" for p, c in row.get("controls", {}).items()))
    return {"dataset": str(dataset), "test_ratio": test_ratio, "split_seed": split_seed,
            "items": int(len(items.hand)), "config": dataclasses.asdict(cfg), "tasks": out}


def _fmt(x) -> str:
    return "–" if x is None else f"{x:.3f}"


def markdown(doc: dict) -> str:
    default = dataclasses.asdict(RGBPretrainConfig())
    changed = {k: v for k, v in doc["config"].items() if k not in ("seed", "max_items") and default.get(k) != v}
    probe = ("the smoke's config" if not changed else
             "the smoke's config with " + ", ".join(f"`{k}={json.dumps(v)}`" for k, v in changed.items()))
    lines = ["# RGB probe: leave-one-task-out transfer", "",
             f"Dataset `{doc['dataset']}`, {doc['items']} items decoded, probe seed {doc['config']['seed']}, "
             f"split seed {doc['split_seed']}. For each task, a probe of "
             f"{probe} trained on the other tasks' train episodes; covered-cell MSE / all zeros "
             "(below 1: better than all zeros) on the other tasks' test episodes (seen) and on every "
             "frame of the held-out task (held). `python -m handtouch.task_transfer` (handtouch/task_transfer.py).",
             "", "| Held-out task | Train items | Seen: MSE / zeros | Held-out: MSE / zeros | Held-out items | "
             "RGB transfers |", "|---|---:|---:|---:|---:|---|"]
    for task, row in doc["tasks"].items():
        held = row["held"]["ratio"]
        verdict = "–" if held is None else ("yes" if held < 1 else "no")
        lines.append(f"| {task} | {row['train_items']} | {_fmt(row['seen']['ratio'])} | {_fmt(held)} | "
                     f"{row['held']['items']} | {verdict} |")
    with_controls = {t: r for t, r in doc["tasks"].items() if "controls" in r}
    if with_controls:
        lines += ["", "## Misalignment controls on each split (seen test items)", "",
                  "The smoke's control (handtouch/rgb_pretrain.py) on every leave-one-task-out split: probes "
                  "trained with RGB shifted >= 1 s within the episode and with RGB of another episode, each "
                  "scored under its own pairing; gap = control's ratio - the aligned probe's (above 0: the "
                  "aligned pairing predicts better).", "",
                  "| Held-out task | Aligned | Shifted | Shifted gap | Shuffled | Shuffled gap |",
                  "|---|---:|---:|---:|---:|---:|"]
        for task, row in with_controls.items():
            a, c = row["seen"]["ratio"], row["controls"]
            gap = {p: None if a is None or c[p]["ratio"] is None else c[p]["ratio"] - a for p in c}
            lines.append(f"| {task} | {_fmt(a)} | {_fmt(c['shifted']['ratio'])} | {_fmt(gap['shifted'])} | "
                         f"{_fmt(c['shuffled']['ratio'])} | {_fmt(gap['shuffled'])} |")
    return "\n".join(lines) + "\n"


def probe_fields(ap: argparse.ArgumentParser, items: list[str]) -> dict:
    """["steps=600", ...] -> {"steps": 600}, values read as `--set` reads them (config.parse_override);
    unknown fields are an argparse error naming the known ones."""
    known = {f.name for f in dataclasses.fields(RGBPretrainConfig)} - {"seed", "max_items"}
    out = {}
    for item in items:
        path, value = parse_override(item) if "=" in item else ([], None)
        if len(path) != 1 or path[0] not in known:
            ap.error(f"--probe {item!r}: expected FIELD=VALUE with FIELD one of {sorted(known)}")
        out[path[0]] = value
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m handtouch.task_transfer", description=__doc__.splitlines()[0],
                                 epilog=__doc__.split("\n\n", 2)[2], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", type=Path, required=True, help="committed dataset directory")
    ap.add_argument("--out", type=Path, required=True, help="folder for task_transfer.{json,md} and the probes")
    ap.add_argument("--tasks", default="", help="comma list of tasks to hold out (default: every task)")
    ap.add_argument("--seed", type=int, default=0, help="probe init, batches and augmentation (default 0)")
    ap.add_argument("--split-seed", type=int, default=0,
                    help="seed of the test episodes' hash, as `htdata split --seed` (default 0: the smoke's)")
    ap.add_argument("--controls", action="store_true",
                    help="also train the shifted and shuffled control probes on each split (3x the time)")
    ap.add_argument("--max-items", type=int, default=RGBPretrainConfig.max_items * 2,
                    help="frames decoded from the whole dataset (a seeded subsample; default %(default)s)")
    ap.add_argument("--probe", action="append", default=[], metavar="FIELD=VALUE",
                    help="a field of the probe's RGBPretrainConfig (default: the smoke's), e.g. steps=600; "
                         "VALUE is read as TOML, else as text (as --set elsewhere)")
    args = ap.parse_args(argv)
    cfg = RGBPretrainConfig(seed=args.seed, max_items=args.max_items, **probe_fields(ap, args.probe)).validate()
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    (args.out / "probes").mkdir(parents=True, exist_ok=True)
    doc = transfer_table(args.dataset, cfg, tasks, probe_dir=args.out / "probes", controls=args.controls,
                         split_seed=args.split_seed)
    write_json_atomic(args.out / "task_transfer.json", doc)
    text = markdown(doc)
    write_text_atomic(args.out / "task_transfer.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
