"""The same ingest under another revision of htdata, side by side: what each change since then cost.

`revision_rows` exports the base revision (default c42b4ea, the round-one
code) from the git checkout this htdata runs from (`git archive`), then
alternates base and current code `reps` times on the same inputs, each run in
a fresh interpreter importing its own tree first (PYTHONPATH, HTDATA_ROOT):

- one moving 600-frame TouchAnything episode, inline (`--workers 0`): wall
  seconds and the child's own peak RSS (VmHWM), the episode issue #22 names;
- the small sample corpus, every source it writes (htdata.synthetic.corpus.FORMATS;
  one the base revision has no pipeline for is left out of both), 1 worker: frames/s.

Ratios are current / base, medians over the pairs. An installed htdata (no
checkout, or a checkout without the base commit) cannot do this: the section
then says why instead of a number. tools/bench_compare.py adds reads, torch
items and validate for any two revisions.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from htdata.synthetic.corpus import FORMATS as CORPUS_FORMATS  # the sample corpus's sources, one pipeline each

ROUND_ONE = "c42b4ea"

# The child reports its own peak RSS (VmHWM: exec resets it; ru_maxrss would carry the parent's) and
# imports nothing from the benchmarks, so it runs under any revision.
_CHILD = """
import sys
from htdata.cli import main
rc = main(sys.argv[1:])
hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM:")]
print("PEAK_KB", hwm[0].split()[1] if hwm else -1, rc)
"""


def checkout_root() -> Path | None:
    """The git checkout this htdata was imported from, or None (an installed wheel)."""
    root = Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "--show-toplevel"], capture_output=True,
                             text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return Path(out) if Path(out).resolve() == root else None


def export_revision(repo: Path, rev: str, into: Path) -> Path:
    """The tree of `rev` as a plain folder (replaced if it exists)."""
    if into.exists():
        shutil.rmtree(into)
    into.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(repo), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def run_ingest(tree: Path, args: list[str]) -> dict:
    """`htdata ingest ARGS` with `tree`'s code in a fresh interpreter: wall seconds, peak RSS MiB."""
    env = {**os.environ, "PYTHONPATH": str(tree), "HTDATA_ROOT": str(tree)}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, "ingest", "--quiet", *args], cwd=tree, env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    line = [ln.split() for ln in proc.stdout.splitlines() if ln.startswith("PEAK_KB")]
    if proc.returncode != 0 or not line or line[0][2] != "0":
        raise RuntimeError(f"ingest under {tree} failed: {proc.stderr[-1500:]}")
    return {"wall_s": wall, "peak_rss_mb": int(line[0][1]) / 1024.0}


def _pipelines(tree: Path, sources: dict[str, Path]) -> list[str]:
    return [a for name, root in sources.items() for a in ("--pipeline", f"{tree / 'pipelines' / name}.toml={root}")]


def revision_rows(work: Path, episode: Path, corpus: Path, base: str = ROUND_ONE, reps: int = 3,
                  corpus_reps: int = 2, adapters: tuple[str, ...] = CORPUS_FORMATS) -> dict:
    """Base revision vs the current code (see the module docstring); {"skipped": why} without a checkout."""
    work, episode, corpus = Path(work).resolve(), Path(episode).resolve(), Path(corpus).resolve()  # children run in the trees
    repo = checkout_root()
    if repo is None:
        return {"base": base, "skipped": "htdata is not running from a git checkout (installed package)"}
    if subprocess.run(["git", "-C", str(repo), "cat-file", "-e", f"{base}^{{commit}}"],
                      capture_output=True).returncode != 0:
        return {"base": base, "skipped": f"commit {base} is not in {repo} (shallow clone?)"}
    trees = {"base": export_revision(repo, base, work / "revision_base"), "current": repo}
    adapters = tuple(a for a in adapters if (trees["base"] / "pipelines" / f"{a}.toml").is_file())
    cases = {"episode_600": (_pipelines_for(trees, {"touchanything": episode}, ["--workers", "0"]), reps),
             "corpus_1w": (_pipelines_for(trees, {a: corpus / a for a in adapters}, ["--workers", "1"]), corpus_reps)}
    rows = []
    for case, (args_of, n) in cases.items():
        runs: dict[str, list[dict]] = {"base": [], "current": []}
        for rep in range(n):
            for name, tree in trees.items():
                out = work / f"revision_{case}_{name}"
                if out.exists():
                    shutil.rmtree(out)
                runs[name].append({**run_ingest(tree, [*args_of[name], str(out)]),
                                   "frames": _samples(out)})
                shutil.rmtree(out)
        pairs = list(zip(runs["base"], runs["current"]))
        rows.append({"case": case, "reps": n, "frames": runs["current"][0]["frames"],
                     "base_wall_s": float(np.median([r["wall_s"] for r in runs["base"]])),
                     "current_wall_s": float(np.median([r["wall_s"] for r in runs["current"]])),
                     "wall_ratio": float(np.median([c["wall_s"] / b["wall_s"] for b, c in pairs])),
                     "base_peak_rss_mb": float(np.median([r["peak_rss_mb"] for r in runs["base"]])),
                     "current_peak_rss_mb": float(np.median([r["peak_rss_mb"] for r in runs["current"]])),
                     "rss_ratio": float(np.median([c["peak_rss_mb"] / b["peak_rss_mb"] for b, c in pairs])),
                     "runs": runs})
    return {"base": base, "rows": rows}


def _pipelines_for(trees: dict[str, Path], sources: dict[str, Path], extra: list[str]) -> dict[str, list[str]]:
    return {name: [*extra, *_pipelines(tree, sources)] for name, tree in trees.items()}


def _samples(dataset: Path) -> int:
    return int(json.loads((dataset / "dataset.json").read_text())["counts"]["samples"])
