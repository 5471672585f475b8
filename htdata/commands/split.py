"""`htdata split DATASET --ood-task TASK [...]`: a new version holding split NAME (or --list-tasks)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.curate import split
from htdata.store.lock import DatasetLocked

EPILOG = """\
The episode is the unit: all frames of an episode land in one part (no near-duplicate
neighbouring frames in both train and test). Parts: ood = every episode of the --ood-task
tasks; of the others, round(--test-ratio x their number) go to test, shared among the tasks
by their size; each task's test episodes are the ones with the smallest seeded hash of their
id. Every task of 2+ episodes keeps at least one test and one train episode, so a few small
tasks get more test than the ratio asks (six tasks of 6-7 episodes at 0.1: 6 of 39; the
summary says so); a single-episode task stays in train.
Running split again with the same name and params updates the split: an episode it holds
never moves (also after episodes are added or removed); new episodes fill each task's share.
Nothing new to assign: nothing is committed ("nothing changed: version N stays current").
--force with other params recomputes from scratch, which may place episodes differently.
The split is saved with a new version (versions/vN/splits/NAME.json) and records which
version it was made from. Defaults: --test-ratio 0.1, --seed 0, --name main.

Examples:
  htdata split data/dataset --list-tasks
  htdata split data/dataset --ood-task palm_push --name main
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--ood-task", action="append", default=[], dest="ood_tasks", metavar="TASK",
                        help="task held out whole as out-of-distribution (repeatable)")
    parser.add_argument("--test-ratio", type=float, default=0.1,
                        help="fraction of the in-distribution episodes in test, shared by task; every task of "
                             "2+ episodes keeps one (default 0.1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the episode hash (default 0)")
    parser.add_argument("--name", default=None, help="split name (versions/vN/splits/NAME.json)")
    parser.add_argument("--force", action="store_true",
                        help="recompute a split of that name made with other params (versioned datasets keep "
                             "the old one in the parent version); without it, a split of the same name and "
                             "params is updated: its episodes keep their parts, new ones are assigned")
    parser.add_argument("--list-tasks", action="store_true",
                        help="print tasks with episode and frame counts per scene, then exit")


def run(args: argparse.Namespace) -> int:
    try:
        if args.list_tasks:
            _, episodes = split.read_dataset_episodes(args.dataset)
            print(split.format_task_table(episodes))
            return 0
        result = split.write_split(args.dataset, args.ood_tasks, test_ratio=args.test_ratio, seed=args.seed,
                                   name=args.name, force=args.force,
                                   command="htdata split " + " ".join(sys.argv[2:]))
    except (split.SplitError, DatasetLocked, FileNotFoundError) as exc:
        print(f"htdata split: error: {exc}", file=sys.stderr)
        return 2
    for w in result.doc["warnings"]:
        print(f"htdata split: warning: {w}", file=sys.stderr)
    if not result.changed:    # as ingest: a run that would commit an identical version commits nothing
        print(f"nothing changed: version {result.version} stays current (split {result.doc['name']!r} "
              f"already holds these parts: {result.path})")
        return 0
    print(split.format_summary(result.doc, result.path))
    if result.version is not None:
        changes = [f"{part} +{len(result.gained[part])}/-{len(result.lost[part])}" for part in split.PARTS]
        print(f"  version {result.version}; episodes per part against the parent version: {', '.join(changes)}")
    return 0
