"""A dataset's history: the log of its versions and the episode diff between two of them (`htdata log` / `diff`)."""

from __future__ import annotations

import os

from htdata.store.manifest import load_episodes, load_manifest
from htdata.store.versions import diff_episodes, list_versions


def log_entries(root: str | os.PathLike) -> list[dict]:
    """One entry per version, oldest first: version, parent, time, author, command, summary, current."""
    current = load_manifest(root, validate=False).get("version")
    out = []
    for n in list_versions(root):
        m = load_manifest(root, validate=False, version=n)
        change = m.get("change", {})
        out.append({"version": n, "parent": m.get("parent"), "time": change.get("time", m.get("created")),
                    "author": change.get("author"), "command": change.get("command"),
                    "summary": change.get("summary", {}), "current": n == current,
                    "episodes": m["counts"]["episodes"], "samples": m["counts"]["samples"]})
    return out


def diff_versions(root: str | os.PathLike, a: int, b: int) -> dict:
    """Episodes added / removed / changed from version a to version b (diff_episodes)."""
    old = load_episodes(root, load_manifest(root, validate=False, version=a))
    new = load_episodes(root, load_manifest(root, validate=False, version=b))
    return diff_episodes(old, new)
