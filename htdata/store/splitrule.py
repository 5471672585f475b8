"""The split rule: which part each episode goes to, and the split document it makes.

htdata/curate/split.py documents the rule and `htdata split` commits its documents; `htdata validate`
(htdata/validate/splits.py) and HandTouch's task transfer apply it too, so it lives in the store,
below every writer, and reading it imports none.
"""

from __future__ import annotations

import difflib
import hashlib
import re
from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime, timezone

from htdata.errors import ArgumentError
from htdata.resources import validate_json
from htdata.store.splitfiles import count_parts

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_-]+$")


RULE = (
    "ood: episodes of params.ood_tasks; other episodes: "
    "u = int(sha256(f'{seed}:{episode_id}')[:8 bytes], big-endian) / 2**64; "
    "T = round(test_ratio * in-distribution episodes) test episodes shared among the tasks by largest "
    "remainder of test_ratio * n, each task with n >= 2 episodes getting at least 1 and at most n - 1 "
    "(so T grows to the number of such tasks when that is larger); a task's test episodes are its "
    "smallest-u ones; a single-episode task goes to train; episodes of an earlier split of this name "
    "keep their part and only new episodes fill a task up to its share"
)


class SplitError(ArgumentError):
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


def test_counts(sizes: dict[str, int], test_ratio: float) -> dict[str, int]:
    """{task: in-distribution episodes} -> {task: test episodes} under RULE.

    The total aims at round(test_ratio * all episodes), shared by largest
    remainder of test_ratio * n; every task with >= 2 episodes keeps at least
    one test and one train episode, which can push the total above the aim
    (six tasks of six episodes at 0.1: 6 of 36, not 4). Deterministic: ties go
    by task name.
    """
    quota = {t: test_ratio * n for t, n in sizes.items()}
    low = {t: 1 if n >= 2 else 0 for t, n in sizes.items()}
    high = {t: max(n - 1, 0) for t, n in sizes.items()}
    counts = {t: min(max(int(quota[t]), low[t]), high[t]) for t in sizes}
    aim = round(test_ratio * sum(sizes.values()))
    while sum(counts.values()) < aim:
        room = [t for t in sorted(sizes) if counts[t] < high[t]]
        if not room:
            break
        counts[max(room, key=lambda t: quota[t] - counts[t])] += 1   # max keeps the first of ties
    while sum(counts.values()) > aim:
        room = [t for t in sorted(sizes) if counts[t] > low[t]]
        if not room:
            break
        counts[min(room, key=lambda t: quota[t] - counts[t])] -= 1
    return counts


def assign_episodes(episodes: list[dict], ood_tasks: list[str], test_ratio: float, seed: int,
                    fixed: dict[str, str] | None = None) -> tuple[dict[str, str], list[str]]:
    """episode records (episode_id, task) -> ({episode_id: part}, warnings).

    `fixed`: the parts of an earlier split of this name; those episodes keep
    them and the task's other episodes (smallest u first) fill its test share.
    """
    fixed = fixed or {}
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
        assignment[eid] = "train"
        by_task[ep["task"]].append((episode_uniform(seed, eid), eid))

    counts = test_counts({t: len(m) for t, m in by_task.items()}, test_ratio)
    warnings: list[str] = []
    for task in sorted(by_task):
        kept = {e: fixed[e] for _, e in by_task[task] if fixed.get(e) in ("train", "test")}
        free = [e for _, e in sorted(by_task[task]) if e not in kept]
        n_test = min(max(counts[task] - sum(p == "test" for p in kept.values()), 0), len(free))
        if n_test == len(free) and free and "train" not in kept.values():
            n_test -= 1     # a task keeps a train episode
        assignment.update(kept)
        assignment.update({e: "test" for e in free[:n_test]})
        if len(by_task[task]) == 1 and not kept:
            warnings.append(f"task {task!r} has a single episode ({free[0]}): it goes to train, "
                            f"so this task has no test episode")
    return assignment, warnings


def build_split(episodes: list[dict], config: SplitConfig, manifest_sha256: str | None = None,
                episodes_sha256: str | None = None, fixed: dict[str, str] | None = None) -> dict:
    """Pure part of `make_split`: the split document for these episode records.

    `fixed`: episode -> part of the earlier split of this name (an update: they keep their parts).

    A split of a versioned dataset (format_version 2) names the episode file
    it describes (`episodes_sha256`); an unversioned one (v1) its manifest.
    """
    config.validate()
    check_ood_tasks([ep["task"] for ep in episodes], config.ood_tasks)
    assignment, warnings = assign_episodes(
        episodes, config.ood_tasks, float(config.test_ratio), int(config.seed), fixed)

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
        "corrections": [],   # the stratified rule corrects nothing; splits made by the older threshold rule list theirs
        "warnings": warnings,
    }
    validate_json(doc, "split", where=f"split {doc['name']!r}")
    return doc
