"""`htdata split`: task-level OOD hold-out plus a seeded, stratified train/test split.

The episode is the unit: all frames of an episode land in one part, so no
near-duplicate neighbouring frames leak between train and test.

Assignment rule (written into every split file as "rule"):

1. Episodes of the ``--ood-task`` tasks go whole to ``ood``.
2. Every other episode gets ``u = first 8 bytes of sha256(f"{seed}:{episode_id}")
   / 2**64``, uniform in [0, 1). It goes to ``test`` iff ``u < test_ratio``,
   else to ``train``. The decision depends only on the episode itself, so
   adding episodes later never moves an existing one (this is the stability
   guarantee, tested in tests/test_split.py).
3. Corrections, only for a task with >= 2 episodes whose threshold
   assignment left a part empty: if no episode is below the threshold the
   episode with the smallest ``u`` goes to test; if every episode is below
   it, the one with the largest ``u`` goes to train. Each correction is
   listed in the file's ``corrections``. Only corrected episodes can move
   when episodes are added (e.g. the task later gets an episode below the
   threshold, so its correction is no longer needed). No rule can be both
   fully stable and give every task a train and a test episode: for three
   episodes of one task, each pair alone would need one test and one train
   episode, which no fixed labelling of the three satisfies.
4. A task with a single episode puts it in ``train`` (a test episode with no
   training episode of its task would measure OOD, not held-out episodes),
   with a warning.

A split records the sha256 of the dataset.json it was made from, so
`htdata validate --split` can tell a split made for another commit.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import re
from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from htdata.format import EPISODES_FILE, MANIFEST_FILE, SPLITS_DIR
from htdata.fsutil import write_json_atomic
from htdata.manifest import parse_episodes, parse_manifest
from htdata.resources import validate_json
from htdata.splitversions import PARTS, count_parts
from htdata.versions import split_file

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_-]+$")
RULE = (
    "ood: episodes of params.ood_tasks; other episodes: "
    "u = int(sha256(f'{seed}:{episode_id}')[:8 bytes], big-endian) / 2**64, "
    "test iff u < test_ratio else train; per task with >= 2 episodes, if no "
    "episode is test the smallest-u one is moved to test, if all are test the "
    "largest-u one is moved to train (listed in corrections); a single-episode "
    "task goes to train"
)


class SplitError(ValueError):
    """A split request that cannot be honoured (message says why and what to do)."""


@dataclass
class SplitConfig:
    ood_tasks: list[str]
    test_ratio: float = 0.1
    seed: int = 0
    name: str | None = None
    force: bool = False

    def validate(self) -> None:
        if not self.ood_tasks:
            raise SplitError("at least one --ood-task is required (see --list-tasks)")
        if len(set(self.ood_tasks)) != len(self.ood_tasks):
            raise SplitError(f"--ood-task given twice: {self.ood_tasks}")
        if not (0.0 < float(self.test_ratio) < 1.0):
            raise SplitError(f"--test-ratio must be in (0, 1), got {self.test_ratio}")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise SplitError(f"--seed must be an integer, got {self.seed!r}")
        if self.name is not None and not NAME_PATTERN.match(self.name):
            raise SplitError(f"split name {self.name!r} must match [A-Za-z0-9_-]+ (it is a file name)")

    def resolved_name(self) -> str:
        if self.name is not None:
            return self.name
        tasks = "+".join(sorted(self.ood_tasks))
        tasks = re.sub(r"[^A-Za-z0-9_-]+", "-", tasks).strip("-") or "ood"
        return f"ood-{tasks}-seed{self.seed}"[:120]


def episode_uniform(seed: int, episode_id: str) -> float:
    """Seeded hash of an episode id -> u in [0, 1); depends on nothing else."""
    digest = hashlib.sha256(f"{seed}:{episode_id}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def check_ood_tasks(known_tasks: list[str], ood_tasks: list[str]) -> None:
    """Unknown tasks (with near-match suggestions) and an OOD set that leaves nothing to train on."""
    known = sorted(set(known_tasks))
    for task in ood_tasks:
        if task not in known:
            near = difflib.get_close_matches(task, known, n=3, cutoff=0.5)
            hint = f"; did you mean {', '.join(repr(n) for n in near)}?" if near else ""
            raise SplitError(f"unknown task {task!r}{hint} known tasks: {', '.join(known) or '(none)'}")
    remaining = [t for t in known if t not in set(ood_tasks)]
    if not remaining:
        raise SplitError(
            f"--ood-task {', '.join(ood_tasks)} covers every task of the dataset "
            f"({', '.join(known)}): nothing is left for train/test"
        )


def assign_episodes(episodes: list[dict], ood_tasks: list[str], test_ratio: float,
                    seed: int) -> tuple[dict[str, str], list[dict], list[str]]:
    """episode records (episode_id, task) -> ({episode_id: part}, corrections, warnings)."""
    ood = set(ood_tasks)
    by_task: dict[str, list[tuple[float, str]]] = defaultdict(list)
    assignment: dict[str, str] = {}
    for ep in episodes:
        eid = ep["episode_id"]
        if eid in assignment:
            raise SplitError(f"episode id {eid!r} appears twice in episodes.jsonl")
        if ep["task"] in ood:
            assignment[eid] = "ood"
            continue
        u = episode_uniform(seed, eid)
        assignment[eid] = "test" if u < test_ratio else "train"
        by_task[ep["task"]].append((u, eid))

    corrections: list[dict] = []
    warnings: list[str] = []
    for task in sorted(by_task):
        members = sorted(by_task[task])
        if len(members) == 1:
            u, eid = members[0]
            if assignment[eid] != "train":
                assignment[eid] = "train"
                corrections.append({"episode_id": eid, "task": task, "part": "train",
                                    "reason": "single-episode task goes to train"})
            warnings.append(f"task {task!r} has a single episode ({eid}): it goes to train, "
                            f"so this task has no test episode")
            continue
        n_test = sum(assignment[e] == "test" for _, e in members)
        if n_test == 0:
            eid = members[0][1]
            assignment[eid] = "test"
            corrections.append({"episode_id": eid, "task": task, "part": "test",
                                "reason": f"no episode of {len(members)} had u < {test_ratio}; "
                                          f"smallest u moved to test"})
        elif n_test == len(members):
            eid = members[-1][1]
            assignment[eid] = "train"
            corrections.append({"episode_id": eid, "task": task, "part": "train",
                                "reason": f"all {len(members)} episodes had u < {test_ratio}; "
                                          f"largest u moved to train"})
    return assignment, corrections, warnings


def build_split(episodes: list[dict], config: SplitConfig, manifest_sha256: str | None = None,
                episodes_sha256: str | None = None) -> dict:
    """Pure part of `make_split`: the split document for these episode records.

    A split of a versioned dataset (format_version 2) names the episode file
    it describes (`episodes_sha256`); an unversioned one (v1) its manifest.
    """
    config.validate()
    check_ood_tasks([ep["task"] for ep in episodes], config.ood_tasks)
    assignment, corrections, warnings = assign_episodes(
        episodes, config.ood_tasks, float(config.test_ratio), int(config.seed))

    parts, tasks, ratios = count_parts(assignment, episodes)
    doc = {
        "format": "htdata-split",
        "format_version": 1 if episodes_sha256 is None else 2,
        "name": config.resolved_name(),
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "params": {"ood_tasks": sorted(config.ood_tasks), "test_ratio": float(config.test_ratio),
                   "seed": int(config.seed)},
        "rule": RULE,
        **({"manifest_sha256": manifest_sha256} if episodes_sha256 is None else {"episodes_sha256": episodes_sha256}),
        "parts": parts,
        "ratios": ratios,
        "tasks": tasks,
        "corrections": corrections,
        "warnings": warnings,
    }
    validate_json(doc, "split", where=f"split {doc['name']!r}")
    return doc


def _current_manifest(dataset) -> dict | None:
    path = Path(dataset) / MANIFEST_FILE
    try:
        return json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None


def split_path(dataset, name: str, manifest: dict | None = None) -> Path:
    """Where split NAME of a dataset's version lives (the current one unless `manifest` is given).

    Versioned: versions/vN/splits/NAME.json (the manifest's "splits" entry);
    written before versions: DATASET/splits/NAME.json.
    """
    manifest = manifest if manifest is not None else _current_manifest(dataset)
    if manifest is not None and "version" in manifest:
        entry = manifest.get("splits", {}).get(name)
        return Path(dataset) / (entry["file"] if entry else split_file(manifest["version"], name))
    return Path(dataset) / SPLITS_DIR / f"{name}.json"


def list_splits(dataset, manifest: dict | None = None) -> list[str]:
    """Names of the splits of a dataset's version (the current one unless `manifest` is given), sorted."""
    manifest = manifest if manifest is not None else _current_manifest(dataset)
    if manifest is not None and "version" in manifest:
        return sorted(manifest.get("splits", {}))
    folder = Path(dataset) / SPLITS_DIR
    return sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []


def read_dataset_episodes(dataset: Path) -> tuple[bytes, list[dict]]:
    """(dataset.json bytes, episode records) of a committed dataset.

    The manifest bytes are parsed (format checked, schema not: a split needs
    only the episode records) and returned as read, for the split's
    manifest_sha256; the episodes are read from the file the manifest names.
    """
    dataset = Path(dataset)
    manifest_path = dataset / MANIFEST_FILE
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
    from htdata.splitversions import SplitResult, write_versioned_split

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
    lines.append(f"  test / (train+test): {r['test_of_in_distribution']['episodes']:.3f} of episodes, "
                 f"{r['test_of_in_distribution']['frames']:.3f} of frames "
                 f"(asked {doc['params']['test_ratio']})")
    for c in doc["corrections"]:
        lines.append(f"  correction: {c['episode_id']} -> {c['part']} ({c['reason']})")
    return "\n".join(lines)
