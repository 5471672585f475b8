"""`htdata upgrade`: the current version stored again in today's format, as a new version.

A dataset written by an older htdata (format 3: every version its own episodes.jsonl and
index.npy) stays readable as it is; its next write stores the new version as segments
(format 4, htdata/store/segments.py) anyway. `upgrade` makes that step on its own: a new
version with the same episodes, samples, shards and splits, stored as segments, so later
writes cost what they change. No shard is read or rewritten; the old versions stay readable
until `htdata gc`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from htdata.format.table import FORMAT_VERSION
from htdata.write.newversion import NewVersion


@dataclass
class UpgradePlan:
    """What an upgrade does: the current version and its format, and whether a new version is needed."""
    version: int | None
    format_version: int
    episodes: int
    samples: int

    @property
    def needed(self) -> bool:
        return self.format_version < FORMAT_VERSION

    def lines(self, dry_run: bool) -> list[str]:
        """What the plan says, a line each.

        Args:
            dry_run: word it as what would happen.
        """
        if not self.needed:
            return [f"version {self.version} is format {self.format_version} already: nothing to do"]
        would = "would store" if dry_run else "stores"
        return [f"version {self.version} (format {self.format_version}): {self.episodes} episodes, {self.samples} "
                f"samples; a new version {would} them as format {FORMAT_VERSION} segments (no shard is rewritten)"]


def upgrade(root: str | Path, dry_run: bool, command: str) -> tuple[UpgradePlan, dict | None]:
    """Plan, and unless `dry_run` or not needed, commit the current version again in format FORMAT_VERSION.

    Args:
        root: the dataset folder (local).
        dry_run: plan only, write nothing.
        command: the command line, kept in the new version's change record.

    Returns:
        The plan, and the new version's manifest (None when nothing was written).
    """
    with NewVersion(root, command, new_units=False) as nv:
        parent = nv.parent
        stored = parent.stored or parent.manifest
        plan = UpgradePlan(version=parent.version, format_version=int(stored.get("format_version", 1)),
                           episodes=len(parent.episodes), samples=int(parent.manifest["counts"]["samples"]))
        if dry_run or not plan.needed:
            return plan, None
        return plan, nv.commit(parent.parts())
