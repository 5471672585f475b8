"""The ingest driver's serial work of two revisions, at two corpus sizes, in one run.

    .venv/bin/python tools/driver_compare.py BASE_REV [NEW_REV] [--source opentouch] [--reps 2] [--workers 2]
                                             [--sizes tiny,medium] [--episode-frames 300,330]
                                             [--out bench/driver_compare.json]

Both revisions are exported (`git archive`; NEW_REV defaults to the working tree) and ingest
the SOURCE part of the tiny and the medium sample corpora (written once, by BASE) at WORKERS
process-pool workers, each run in a fresh interpreter, alternating BASE, NEW per size and rep.
Per run: the driver's plan_s and commit_s from the report (wall; every revision reports them)
and the driver process's own CPU seconds in the plan, run and commit phases (measured here,
around `htdata.ingest.run.run_units`, so older revisions are measured the same way). The serial
growth per frame is the slope between the two sizes, medians over reps; machines here are
shared, so compare the revisions within one run only. htdata/benchmarks/driver.py measures the
same for the current code (`htdata bench --only driver`).

--sizes: the two corpus scales (smaller first). --episode-frames LO,HI: both corpora written with
episodes of LO..HI frames (`htdata sample --episode-frames`; then NEW writes them, BASE may not
have the option). The glove rest an ingest pools (htdata/ingest/gloverest.py, at most POOL_MAX
recordings a glove: bounded) is timed here around `run.pool_glove_rests` for both revisions and
left out of the "unbounded" growth (rest_cpu_s; the growth rows with and without it).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_compare import export, run_py  # noqa: E402  (a sibling tool)

CHILD = """
import json, sys, time
from pathlib import Path
from htdata.ingest import run as run_module
from htdata.ingest.plan import Source
from htdata.ingest.pipeline import load_pipeline

def main():
    name, root, out, workers = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])
    marks = {}
    real = run_module.run_units
    real_rest = run_module.pool_glove_rests
    marks["rest_s"] = marks["rest_cpu_s"] = 0.0

    def timed_rest(*args, **kwargs):
        t, c = time.perf_counter(), time.process_time()
        try:
            return real_rest(*args, **kwargs)
        finally:
            marks["rest_s"] += time.perf_counter() - t
            marks["rest_cpu_s"] += time.process_time() - c

    def timed(*args, **kwargs):
        marks["run_start"] = time.process_time()
        try:
            return real(*args, **kwargs)
        finally:
            marks["run_end"] = time.process_time()

    run_module.run_units = timed
    run_module.pool_glove_rests = timed_rest
    cpu0 = time.process_time()
    report = run_module.ingest([Source(pipeline=load_pipeline(name), root=root.resolve())], out, workers=workers,
                               progress=False)
    cpu1 = time.process_time()
    t = report["timing"]
    print(json.dumps({"frames": report["samples"], "units": report["units"], "plan_s": t["plan_s"],
                      "commit_s": t["commit_s"], "plan_cpu_s": marks["run_start"] - cpu0,
                      "run_cpu_s": marks["run_end"] - marks["run_start"], "commit_cpu_s": cpu1 - marks["run_end"],
                      "worker_s": t["worker_s"], "rest_s": marks["rest_s"], "rest_cpu_s": marks["rest_cpu_s"]}))

if __name__ == "__main__":
    main()
"""


def one_run(tree: Path, source: str, root: Path, out: Path, workers: int) -> dict:
    shutil.rmtree(out, ignore_errors=True)       # a fresh dataset every run (a re-run would resume)
    _, stdout = run_py(tree, ["-c", CHILD, source, str(root), str(out), str(workers)], cwd=tree)
    return json.loads(stdout.strip().splitlines()[-1])


def summarise(runs: dict[str, list[dict]]) -> dict:
    """Medians per size, the growth per frame (wall and CPU) between the sizes (the first two keys of `runs`,
    smaller first), with and without the pooled glove rest (bounded); the CPU growth per unit (an episode)."""
    med = {}
    for size, rows in runs.items():
        med[size] = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
        med[size]["serial_s"] = statistics.median(r["plan_s"] + r["commit_s"] for r in rows)
        med[size]["serial_cpu_s"] = statistics.median(r["plan_cpu_s"] + r["commit_cpu_s"] for r in rows)
        med[size]["unbounded_cpu_s"] = statistics.median(r["plan_cpu_s"] + r["commit_cpu_s"] - r.get("rest_cpu_s", 0.0)
                                                         for r in rows)
    small, big = (med[s] for s in list(runs)[:2])
    span, units = big["frames"] - small["frames"], big["units"] - small["units"]
    return {"sizes": med, "growth_ms_per_frame": 1e3 * (big["serial_s"] - small["serial_s"]) / span,
            "growth_cpu_ms_per_frame": 1e3 * (big["serial_cpu_s"] - small["serial_cpu_s"]) / span,
            "unbounded_growth_cpu_ms_per_frame": 1e3 * (big["unbounded_cpu_s"] - small["unbounded_cpu_s"]) / span,
            "unbounded_growth_cpu_ms_per_unit": 1e3 * (big["unbounded_cpu_s"] - small["unbounded_cpu_s"]) / max(units, 1),
            "run_cpu_ms_per_frame": 1e3 * big["run_cpu_s"] / big["frames"]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("base")
    p.add_argument("new", nargs="?", default=None)
    p.add_argument("--source", default="opentouch", choices=("opentouch", "touchanything", "native"))
    p.add_argument("--reps", type=int, default=2)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--sizes", default="tiny,medium", help="the two corpus scales, smaller first")
    p.add_argument("--episode-frames", default=None, metavar="LO,HI", help="episodes of LO..HI frames in both")
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    args = p.parse_args(argv)
    sizes = tuple(s.strip() for s in args.sizes.split(","))
    if len(sizes) != 2 or sizes[0] == sizes[1]:
        p.error(f"--sizes takes two different scales, got {args.sizes!r}")
    runs: dict[str, dict[str, list[dict]]] = {name: {size: [] for size in sizes} for name in ("base", "new")}
    length = ["--episode-frames", args.episode_frames] if args.episode_frames else []
    with tempfile.TemporaryDirectory(prefix="htdata-driver-") as tmp:
        tmp = Path(tmp)
        trees = {"base": export(args.base, tmp / "base"), "new": export(args.new, tmp / "new")}
        writer = trees["new" if length else "base"]
        for size in sizes:
            run_py(writer, ["-m", "htdata.cli", "sample", str(tmp / size), "--seed", "0", "--scale", size,
                            "--formats", args.source, "--quiet", *length], cwd=writer)
        for rep in range(args.reps):
            for size in sizes:
                for name in ("base", "new"):
                    row = one_run(trees[name], args.source, tmp / size / args.source, tmp / f"ds_{name}_{size}",
                                  args.workers)
                    runs[name][size].append(row)
                    print(f"rep {rep} {size} {name}: {row}", file=sys.stderr)
    result = {"base": args.base, "new": args.new or "working tree", "source": args.source, "reps": args.reps,
              "workers": args.workers, "sizes": list(sizes), "episode_frames": args.episode_frames, **{name: summarise(runs[name]) for name in runs}, "runs": runs}
    print(f"| {args.source}, {args.workers} workers, median of {args.reps} | base {args.base} | "
          f"new {args.new or 'working tree'} |")
    print("|---|---|---|")
    for size in sizes:
        for key in ("frames", "units", "serial_s", "serial_cpu_s", "rest_cpu_s"):
            print(f"| {size} {key} | {result['base']['sizes'][size][key]:.4g} | {result['new']['sizes'][size][key]:.4g} |")
    for key in ("growth_ms_per_frame", "growth_cpu_ms_per_frame", "unbounded_growth_cpu_ms_per_frame",
                "unbounded_growth_cpu_ms_per_unit", "run_cpu_ms_per_frame"):
        print(f"| {key} | {result['base'][key]:.4f} | {result['new'][key]:.4f} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
