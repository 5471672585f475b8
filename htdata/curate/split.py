"""`htdata split`: task-level OOD hold-out plus a seeded, stratified train/test split.

The episode is the unit: all frames of an episode land in one part, so no
near-duplicate neighbouring frames leak between train and test.

Assignment rule (written into every split file as "rule"):

1. Episodes of the ``--ood-task`` tasks go whole to ``ood``.
2. Every other episode gets ``u = first 8 bytes of sha256(f"{seed}:{episode_id}")
   / 2**64``, uniform in [0, 1): its place in its task's queue for test.
3. Stratified by task from the start (``splitrule.test_counts``): the split
   aims at ``round(test_ratio * N)`` test episodes of the N in-distribution
   ones, shared among the tasks by largest remainder of ``test_ratio * n``;
   every task with n >= 2 episodes gets at least one test and one train
   episode, which can lift the total above the aim (six tasks of 6-7
   episodes at 0.1: 6 of 39). A task's test episodes are its smallest-u ones.
4. A task with a single episode puts it in ``train`` (a test episode with no
   training episode of its task would measure OOD, not held-out episodes),
   with a warning.
5. Stability: re-running ``htdata split`` with the same name and params
   UPDATES the split of the current version: every episode it held keeps its
   part (tests/curate/test_split.py), and only new episodes are assigned, filling
   each task up to its share. Recomputing from scratch (``--force`` with
   other params, or another name) may place episodes differently.

A split records the sha256 of the dataset.json it was made from, so
`htdata validate --split` can tell a split made for another commit.
"""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from pathlib import Path

from htdata._moved import moved_name
from htdata.curate.splitversions import SplitResult, write_versioned_split
from htdata.fileio import write_json_atomic
from htdata.format.table import EPISODES_FILE, MANIFEST_FILE
from htdata.store.manifest import load_episodes, parse_episodes, parse_manifest
from htdata.store.segments import segmented
from htdata.store.splitfiles import PARTS, split_path
from htdata.store.splitrule import SplitConfig, SplitError, build_split
from htdata.store.versions import manifest_path as current_manifest_path


def read_dataset_episodes(dataset: Path) -> tuple[bytes, list[dict]]:
    """(dataset.json bytes, episode records) of a committed dataset.

    The manifest bytes are parsed (format checked, schema not: a split needs
    only the episode records) and returned as read, for the split's
    manifest_sha256; the episodes are read from the file the manifest names.
    """
    dataset = Path(dataset)
    try:   # the newest version file: dataset.json is only its cache (htdata/store/versions.py)
        manifest_path = Path(current_manifest_path(dataset, None))
    except ValueError as exc:
        raise SplitError(str(exc)) from None
    if not manifest_path.is_file():
        raise SplitError(f"{dataset}: no {MANIFEST_FILE} (not a committed htdata dataset)")
    manifest_bytes = manifest_path.read_bytes()
    try:
        manifest = parse_manifest(manifest_bytes, str(manifest_path), validate=False)
    except json.JSONDecodeError as exc:
        raise SplitError(f"{manifest_path}: invalid JSON: {exc}") from exc
    except ValueError as exc:
        raise SplitError(str(exc)) from exc
    episodes_path = dataset / manifest.get("episodes_file", EPISODES_FILE)
    try:
        if segmented(manifest):    # format 4: the records are in its segments (htdata/store/segments.py)
            episodes_path = Path(manifest_path)
            episodes = load_episodes(dataset, manifest)
        else:
            episodes = parse_episodes(episodes_path.read_text(encoding="utf-8"), str(episodes_path))
    except ValueError as exc:      # names the file and line
        raise SplitError(str(exc)) from exc
    for number, rec in enumerate(episodes, 1):
        for key in ("episode_id", "task", "scene", "num_frames"):
            if key not in rec:
                raise SplitError(f"{episodes_path}: episode record {number} "
                                 f"({rec.get('episode_id', '?')}) lacks {key!r}")
    return manifest_bytes, episodes


def make_split(dataset, ood_tasks, test_ratio: float = 0.1, seed: int = 0,
               name: str | None = None, force: bool = False) -> dict:
    """Compute a split of a committed dataset and write it; returns the split document."""
    return write_split(dataset, ood_tasks, test_ratio, seed, name, force).doc


def write_split(dataset, ood_tasks, test_ratio: float = 0.1, seed: int = 0, name: str | None = None,
                force: bool = False, command: str = "htdata split"):
    """Split a dataset -> splitversions.SplitResult. A versioned dataset gets a new version
    (splitversions.py); an unversioned one (written before versions) gets DATASET/splits/NAME.json."""
    dataset = Path(dataset)
    config = SplitConfig(ood_tasks=list(ood_tasks), test_ratio=test_ratio, seed=seed,
                         name=name, force=force)
    config.validate()
    manifest_bytes, episodes = read_dataset_episodes(dataset)
    if "version" in json.loads(manifest_bytes):
        return write_versioned_split(dataset, config, command)
    out = split_path(dataset, config.resolved_name())
    if out.exists() and not force:
        raise SplitError(f"split {config.resolved_name()!r} already exists at {out}; "
                         f"choose another --name or pass --force to overwrite it")
    doc = build_split(episodes, config, hashlib.sha256(manifest_bytes).hexdigest())
    write_json_atomic(out, doc)
    return SplitResult(doc=doc, path=out, version=None)


def task_table(episodes: list[dict]) -> list[tuple[str, str, int, int]]:
    """(task, scene, episodes, frames) rows sorted by task then scene."""
    counts: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    for ep in episodes:
        c = counts[(ep["task"], ep["scene"])]
        c[0] += 1
        c[1] += int(ep["num_frames"])
    return [(t, s, c[0], c[1]) for (t, s), c in sorted(counts.items())]


def format_task_table(episodes: list[dict]) -> str:
    rows = task_table(episodes)
    totals: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for task, _, n, f in rows:
        totals[task][0] += n
        totals[task][1] += f
    w_task = max([len("task")] + [len(r[0]) for r in rows])
    w_scene = max([len("scene"), len("(all scenes)")] + [len(r[1]) for r in rows])
    lines = [f"{'task':<{w_task}}  {'scene':<{w_scene}}  {'episodes':>8}  {'frames':>8}"]
    for task in sorted(totals):
        for t, scene, n, f in rows:
            if t == task:
                lines.append(f"{task:<{w_task}}  {scene:<{w_scene}}  {n:>8}  {f:>8}")
        n, f = totals[task]
        lines.append(f"{task:<{w_task}}  {'(all scenes)':<{w_scene}}  {n:>8}  {f:>8}")
    lines.append(f"{len(totals)} tasks, {sum(t[0] for t in totals.values())} episodes, "
                 f"{sum(t[1] for t in totals.values())} frames")
    return "\n".join(lines)


def format_summary(doc: dict, path: Path) -> str:
    p = doc["parts"]
    r = doc["ratios"]
    lines = [f"wrote {path}"]
    for part in PARTS:
        lines.append(f"  {part:<5} {len(p[part]['episodes']):>6} episodes {p[part]['frames']:>9} frames")
    n_test, n_in = len(p["test"]["episodes"]), len(p["test"]["episodes"]) + len(p["train"]["episodes"])
    aim = round(doc["params"]["test_ratio"] * n_in)
    why = (f"; {n_test} test episodes rather than {aim}: every task of 2+ episodes keeps one"
           if n_test > aim else "")
    lines.append(f"  test / (train+test): {r['test_of_in_distribution']['episodes']:.3f} of episodes, "
                 f"{r['test_of_in_distribution']['frames']:.3f} of frames "
                 f"(asked {doc['params']['test_ratio']}{why})")
    for c in doc["corrections"]:
        lines.append(f"  correction: {c['episode_id']} -> {c['part']} ({c['reason']})")
    return "\n".join(lines)


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
