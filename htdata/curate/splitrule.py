"""The split rule: which part each episode goes to (the rule itself is documented in split.py)."""

from __future__ import annotations

import difflib
import hashlib
import re
from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime, timezone

from htdata.resources import validate_json
from htdata.store.splitfiles import count_parts


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
