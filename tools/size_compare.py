"""The dataset at HT-Bench's size under two revisions of htdata, side by side (issue 47, item 3).

    .venv/bin/python tools/size_compare.py BASE_REV [NEW_REV] [--samples 1000000,3000000] [--out FILE.json]

Each revision is exported (tools/bench_compare.py `export`: `git archive`, or the working tree when
NEW_REV is left out) and run in its own interpreter, importing its own tree first:
`htdata.benchmarks.htbenchsize.size_rows` ingests the sample raw-count glove with that revision's
writer, replicates it to each size (one commit), and runs the same commands, each its own process
(open, log, split, rm, trim, diff, view, gc). A revision before the segments writes format 3 (every
version its own episodes.jsonl and index.npy), one after them format 4. The revisions run one after
the other, A then B for each size: the bytes written are exact and the same on any machine; the wall
seconds and peak memory come from the same machine minutes apart, so read them as ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from bench_compare import commit_of, export  # noqa: E402  (the same export as the other comparisons)

CHILD = """
import json, sys
from pathlib import Path
from htdata.benchmarks.htbenchsize import size_rows
print("SIZE_JSON " + json.dumps(size_rows(Path(sys.argv[1]), tuple(int(x) for x in sys.argv[2].split(",")))))
"""


def run_revision(tree: Path, work: Path, samples: int) -> dict:
    """One size under the revision exported at `tree`: the shape and every command's figures."""
    env = {**os.environ, "PYTHONPATH": str(tree), "HTDATA_ROOT": str(tree)}
    done = subprocess.run([sys.executable, "-c", CHILD, str(work), str(samples)], cwd=tree, env=env,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{tree}: size {samples} failed:\n{done.stderr[-3000:]}")
    line = next(x for x in done.stdout.splitlines() if x.startswith("SIZE_JSON "))
    return json.loads(line[len("SIZE_JSON "):])["sizes"][0]


def table(a: dict, b: dict, names: tuple[str, str]) -> list[str]:
    """Markdown: one row per command both revisions ran, A and B side by side with B / A."""
    lines = [f"{a['samples']:,} samples, {a['episodes']:,} episodes, {a['units']:,} units; format "
             f"{a.get('format_version', 3)} ({names[0]}) against {b.get('format_version', 3)} ({names[1]}):", "",
             f"| command | wall s {names[0]} / {names[1]} | peak MiB {names[0]} / {names[1]} | bytes written "
             f"{names[0]} / {names[1]} | cache bytes {names[1]} |", "|---|---|---|---|---|"]
    by_name = {c["command"].split(" (")[0]: c for c in a["commands"]}
    for c in b["commands"]:
        old = by_name.get(c["command"].split(" (")[0])
        if old is None:
            continue
        lines.append(f"| {c['command']} | {old['wall_s']:.2f} / {c['wall_s']:.2f} | {old['peak_mib']:.0f} / "
                     f"{c['peak_mib']:.0f} | {old['bytes_written']:,} / {c['bytes_written']:,} | "
                     f"{c.get('cache_bytes_written', 0):,} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("base")
    ap.add_argument("new", nargs="?", default=None, help="default: the working tree")
    ap.add_argument("--samples", default="1000000", help="comma list of sizes (default 1000000)")
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    args = ap.parse_args(argv)
    names = (commit_of(args.base), commit_of(args.new) if args.new else "working tree")
    out = {"revisions": names, "sizes": []}
    with tempfile.TemporaryDirectory(prefix="size_compare_") as tmp:
        trees = [export(args.base, Path(tmp) / "a"), export(args.new, Path(tmp) / "b")]
        for n in (int(x) for x in args.samples.split(",")):
            a, b = (run_revision(tree, Path(tmp) / f"work_{k}", n) for k, tree in zip("ab", trees))
            out["sizes"].append({"base": a, "new": b})
            print("\n".join(table(a, b, names)) + "\n", flush=True)
    if args.out:
        args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
