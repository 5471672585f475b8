"""Compare two revisions of htdata side by side, in one run: ingest, random reads, torch items, validate.

    .venv/bin/python tools/bench_compare.py BASE_REV [NEW_REV] [--reps 3] [--out bench/compare.json] [--glove-only]

Each revision is exported with `git archive` to a temp folder and imported
from there (PYTHONPATH first, so the installed checkout does not shadow it).
Measurements alternate A, B, A, B ... on the same sample corpus, and the
report gives per-revision medians and the ratio NEW/BASE: machines here are
shared and noisy, so only ratios taken in one run mean anything. NEW_REV
defaults to the working tree (uncommitted changes included).

Rows: ingest of the small sample corpus with 1 worker (frames/s), random
decoded reads through DatasetReader (samples/s), TactileFrameDataset items
(items/s), `htdata validate --deep` with 1 worker (frames/s). Each row runs
in a fresh interpreter, so import and cache effects are the same for both.

`--glove-only`: instead, the sample raw-count glove (`htdata sample --raw-glove`: no video, so
the maps are all there is to encode) ingested with 1 worker, maps stored (the default) and
`--set tactile.maps=raw`, alternating A stored, A raw, B stored, B raw: frames/s of each (the
ingest's own seconds, reports/ingest.json, as the bench section "maps stored vs raw" counts them),
the CPU seconds of the whole command (worker processes included), and stored / raw per revision.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from htdata.benchmarks.revisions import export_revision  # noqa: E402  (the same export as `make bench`)

READS = """
import sys, time, numpy as np
try:   # the current name, else the flat name older revisions have as a real module (no shim needed)
    from htdata.read.reader import DatasetReader
except ImportError:
    from htdata.reader import DatasetReader
r = DatasetReader(sys.argv[1]); n = len(r)
idx = np.random.default_rng(0).integers(0, n, 400)
r.decoded(int(idx[0]))
t = time.perf_counter()
for i in idx: r.decoded(int(i))
print(len(idx) / (time.perf_counter() - t))
"""

ITEMS = """
import sys, time, numpy as np
try:   # (as above)
    from htdata.read.torchdata import TactileFrameDataset
except ImportError:
    from htdata.torchdata import TactileFrameDataset
d = TactileFrameDataset(sys.argv[1]); n = len(d)
idx = np.random.default_rng(0).integers(0, n, 400)
d[int(idx[0])]
t = time.perf_counter()
for i in idx: d[int(i)]
print(len(idx) / (time.perf_counter() - t))
"""


def export(rev: str | None, into: Path) -> Path:
    """The tree of `rev` (None = working tree) as a plain folder."""
    into.mkdir(parents=True)
    if rev is None:
        files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, check=True,
                               capture_output=True, text=True).stdout.split()
        for f in files:
            src = REPO / f
            if src.is_file():
                (into / f).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(src, into / f)
        return into
    return export_revision(REPO, rev, into)


def commit_of(rev: str) -> str:
    """`rev` (a branch, HEAD, ...) as the short commit it names now, so the record says what was measured."""
    return subprocess.run(["git", "rev-parse", "--short", rev], cwd=REPO, check=True, capture_output=True,
                          text=True).stdout.strip()


def run_py(tree: Path, args: list[str], cwd: Path) -> tuple[float, str]:
    env = {**os.environ, "PYTHONPATH": str(tree), "HTDATA_ROOT": str(tree)}
    t = time.perf_counter()
    out = subprocess.run([sys.executable, *args], cwd=cwd, env=env, check=True, capture_output=True, text=True)
    return time.perf_counter() - t, out.stdout


def corpus_formats(raw: Path) -> list[str]:
    """The source formats of the sample corpus at `raw`, in the order `htdata sample` wrote them (its
    `.complete` marker: a new adapter with a corpus writer is compared without a change here); the three
    of a revision whose marker names none."""
    try:
        return list(json.loads((raw / ".complete").read_text())["formats"])
    except (OSError, ValueError, KeyError):
        return ["opentouch", "touchanything", "native"]


def ingest_args(raw: Path, out: Path) -> list[str]:
    args = ["-m", "htdata.cli", "ingest", "--workers", "1", "--quiet"]
    for name in corpus_formats(raw):
        args += ["--pipeline", f"pipelines/{name}.toml={raw / name}"]
    return args + [str(out)]


def measure(tree: Path, raw: Path, work: Path, rep: int) -> dict:
    ds = work / f"ds_{rep}"
    seconds, _ = run_py(tree, ingest_args(raw, ds), cwd=tree)
    frames = json.loads((ds / "dataset.json").read_text())["counts"]["samples"]
    row = {"ingest_frames_per_s": frames / seconds}
    row["reads_per_s"] = float(run_py(tree, ["-c", READS, str(ds)], cwd=tree)[1])
    row["torch_items_per_s"] = float(run_py(tree, ["-c", ITEMS, str(ds)], cwd=tree)[1])
    seconds, _ = run_py(tree, ["-m", "htdata.cli", "validate", str(ds), "--deep", "--workers", "1"], cwd=tree)
    row["validate_frames_per_s"] = frames / seconds
    shutil.rmtree(ds)
    return row


def glove_only_measure(tree: Path, src: Path, work: Path, rep: int) -> dict:
    """One glove-only ingest per maps choice (stored, then raw): frames/s, CPU s, and stored / raw."""
    row = {}
    for choice in ("stored", "raw"):
        out = work / f"glove_{choice}_{rep}"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        run_py(tree, ["-m", "htdata.cli", "ingest", "--pipeline", f"native={src}", "--layouts", str(src / "layouts"),
                      "--set", f"tactile.maps={choice}", "--workers", "1", "--quiet", str(out)], cwd=tree)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        report = json.loads((out / "reports" / "ingest.json").read_text())
        seconds = float((report.get("timing") or {}).get("total_s", report["seconds"]))
        row[f"{choice}_frames_per_s"] = int(report["samples"]) / seconds
        row[f"{choice}_cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        shutil.rmtree(out)
    row["stored_over_raw_speed"] = row["stored_frames_per_s"] / row["raw_frames_per_s"]
    row["stored_over_raw_cpu"] = row["stored_cpu_s"] / row["raw_cpu_s"]
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("base", help="base revision (e.g. a commit before the change)")
    p.add_argument("new", nargs="?", default=None, help="new revision (default: the working tree)")
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    p.add_argument("--glove-only", action="store_true",
                   help="measure the raw-count glove's ingest, maps stored vs raw, instead (see above)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="htdata-compare-") as tmp:
        tmp = Path(tmp)
        trees = {"base": export(args.base, tmp / "base"), "new": export(args.new, tmp / "new")}
        raw = tmp / "raw"
        sample = ["-m", "htdata.cli", "sample", str(raw), "--seed", "0"]
        run_py(trees["base"], sample + (["--raw-glove"] if args.glove_only else ["--scale", "small"]),
               cwd=trees["base"])
        rows: dict[str, list[dict]] = {"base": [], "new": []}
        for rep in range(args.reps):
            for name in ("base", "new"):
                work = tmp / name / "_work"
                work.mkdir(parents=True, exist_ok=True)
                rows[name].append(glove_only_measure(trees[name], raw / "rawglove", work, rep) if args.glove_only
                                  else measure(trees[name], raw, work, rep))
                print(f"rep {rep} {name}: {rows[name][-1]}", file=sys.stderr)
    metrics = list(rows["base"][0])
    table = {m: {"base": statistics.median(r[m] for r in rows["base"]),
                 "new": statistics.median(r[m] for r in rows["new"])} for m in metrics}
    for m in metrics:
        table[m]["ratio_new_over_base"] = table[m]["new"] / table[m]["base"]
    base, new = commit_of(args.base), (commit_of(args.new) if args.new else "working tree")
    result = {"base": base, "new": new, "reps": args.reps, "glove_only": args.glove_only, "median": table,
              "runs": rows}
    print(f"| metric (median of {args.reps}) | base {base} | new {new} | new/base |")
    print("|---|---|---|---|")
    for m in metrics:
        t = table[m]
        print(f"| {m} | {t['base']:.3g} | {t['new']:.3g} | {t['ratio_new_over_base']:.2f} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
