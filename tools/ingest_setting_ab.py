"""One pipeline setting against the default, per adapter, side by side in one run (same code).

    .venv/bin/python tools/ingest_setting_ab.py --set rgb.interpolation=cubic2x_area [--reps 3] [--out ab.json]

Writes the small sample corpus (`htdata sample --scale small`, seed 0) to a temp folder,
then for each adapter ingests it with 1 worker with the shipped pipeline (A) and with
`--set` added (B), alternating A, B / B, A rep by rep. Per run: frames/s (samples over
the ingest's own total seconds, reports/ingest.json `timing`, as `tools/bench_compare.py`
and the bench count them) and the decode / resize stages in ms per frame. Prints per
adapter the medians and B / A, and whether the two datasets' shard members are
byte-identical apart from the RGB JPEGs (first rep). The machine is shared and noisy:
read the ratios, not the absolute numbers.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ADAPTERS = ("opentouch", "touchanything", "native")


def ingest(raw: Path, adapter: str, out: Path, extra: list[str]) -> dict:
    subprocess.run([sys.executable, "-m", "htdata.cli", "ingest", "--workers", "1", "--quiet", "--pipeline",
                    f"pipelines/{adapter}.toml={raw / adapter}", *extra, str(out)],
                   cwd=REPO, check=True, capture_output=True)
    report = json.loads((out / "reports" / "ingest.json").read_text())
    t = report["timing"]
    return {"frames_per_s": report["samples"] / t["total_s"], "decode_ms": 1e3 * t["decode_s"] / t["frames"],
            "resize_ms": 1e3 * t["resize_s"] / t["frames"]}


def members(root: Path) -> dict[str, bytes]:
    found = {}
    for shard in sorted(root.rglob("*.tar")):
        with tarfile.open(shard) as tf:
            for m in tf.getmembers():
                if m.isfile():
                    found[m.name] = tf.extractfile(m).read()
    return found


def compare(a: Path, b: Path) -> dict:
    """Which member kinds (the name after the key's first dot) differ in bytes between two datasets."""
    ma, mb = members(a), members(b)
    differ = sorted({k.split(".", 1)[1] for k in ma if ma[k] != mb.get(k)} | {k.split(".", 1)[1] for k in mb if k not in ma})
    count = {kind: sum(1 for k in ma if k.split(".", 1)[1] == kind and ma[k] != mb.get(k)) for kind in differ}
    return {"members": len(ma), "kinds_differing": count}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--set", dest="sets", action="append", required=True, help="KEY=VALUE for run B (repeatable)")
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    args = p.parse_args(argv)
    extra = [x for s in args.sets for x in ("--set", s)]
    runs: dict[str, dict[str, list[dict]]] = {a: {"A": [], "B": []} for a in ADAPTERS}
    same: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="htdata-ab-") as tmp:
        tmp = Path(tmp)
        raw = tmp / "raw"
        subprocess.run([sys.executable, "-m", "htdata.cli", "sample", str(raw), "--scale", "small", "--seed", "0",
                        "--quiet"], cwd=REPO, check=True, capture_output=True)
        for rep in range(args.reps):
            for adapter in ADAPTERS:
                order = ("A", "B") if rep % 2 == 0 else ("B", "A")
                for side in order:
                    out = tmp / f"{adapter}_{side}_{rep}"
                    runs[adapter][side].append(ingest(raw, adapter, out, extra if side == "B" else []))
                    print(f"rep {rep} {adapter} {side}: {runs[adapter][side][-1]}", file=sys.stderr)
                if rep == 0:
                    same[adapter] = compare(tmp / f"{adapter}_A_0", tmp / f"{adapter}_B_0")
                for side in order:
                    shutil.rmtree(tmp / f"{adapter}_{side}_{rep}")
    summary = {}
    for adapter, sides in runs.items():
        med = {side: {k: statistics.median(r[k] for r in rows) for k in rows[0]} for side, rows in sides.items()}
        summary[adapter] = {**med, "b_over_a": {k: med["B"][k] / med["A"][k] for k in med["A"]},
                            "bytes": same[adapter]}
    print(f"| adapter | A frames/s | B frames/s | B/A frames/s | A resize ms | B resize ms | B/A resize | "
          f"member kinds differing (B: {' '.join(args.sets)}) |")
    print("|---|---|---|---|---|---|---|---|")
    for adapter, s in summary.items():
        kinds = ", ".join(f"{k} {n}" for k, n in s["bytes"]["kinds_differing"].items()) or "none"
        print(f"| {adapter} | {s['A']['frames_per_s']:.1f} | {s['B']['frames_per_s']:.1f} | "
              f"{s['b_over_a']['frames_per_s']:.2f} | {s['A']['resize_ms']:.2f} | {s['B']['resize_ms']:.2f} | "
              f"{s['b_over_a']['resize_ms']:.2f} | {kinds} of {s['bytes']['members']} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"set": args.sets, "reps": args.reps, "summary": summary, "runs": runs},
                                       indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
