"""The dataset lifecycle on the sample corpus, command by command, as a user would type it.

    .venv/bin/python tools/lifecycle_demo.py [WORKDIR]     (default: a fresh temp folder)

ingest source S (OpenTouch) -> ingest source T (TouchAnything) into the same
dataset -> split -> rm (dry run, then for real) -> trim -> a second dataset
(native) merged with the first -> gc -> log and diff -> validate every
version. Prints each command and its output; exits non-zero if any step
fails. This is the transcript quoted in the lifecycle issue's closing note.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

HTDATA = [sys.executable, "-m", "htdata.cli"]


def run(*args: str) -> str:
    print(f"\n$ htdata {' '.join(shlex.quote(a) for a in args)}", flush=True)
    res = subprocess.run([*HTDATA, *args], capture_output=True, text=True)
    out = (res.stdout + res.stderr).rstrip()
    if out:
        print(out)
    if res.returncode != 0:
        raise SystemExit(f"htdata {args[0]} exited {res.returncode}")
    return res.stdout


def main(argv: list[str]) -> int:
    work = Path(argv[0]) if argv else Path(tempfile.mkdtemp(prefix="htdata-lifecycle-"))
    raw, ds, other, merged = work / "raw", work / "ds", work / "native_only", work / "merged"
    run("sample", str(raw), "--seed", "0", "--scale", "small", "--reuse")
    run("ingest", "--quiet", "--workers", "2", "--pipeline", f"opentouch={raw / 'opentouch'}", str(ds))
    run("ingest", "--quiet", "--workers", "2", "--pipeline", f"touchanything={raw / 'touchanything'}", str(ds))
    run("split", str(ds), "--ood-task", "palm_push", "--name", "main")
    episodes = [json.loads(line) for line in (ds / json.loads((ds / "dataset.json").read_text())["episodes_file"])
                .read_text().splitlines()]
    office = sorted(e["episode_id"] for e in episodes if e["episode_id"].startswith("ta-Office-"))
    run("rm", str(ds), "ta-Office-*", "--dry-run")
    run("rm", str(ds), office[0])
    longest = max(episodes, key=lambda e: e["num_frames"])
    run("trim", str(ds), longest["episode_id"], "--frames", f"5:{longest['num_frames'] - 5}")
    run("ingest", "--quiet", "--workers", "2", "--pipeline", f"native={raw / 'native'}", str(other))
    run("merge", str(ds), str(other), str(merged))
    run("log", str(ds))
    run("gc", str(ds), "--keep-versions", "3", "--dry-run")
    run("gc", str(ds), "--keep-versions", "3")
    run("log", str(ds))
    run("log", str(merged))
    versions = [e["version"] for e in json.loads(run("log", str(ds), "--json"))]
    run("diff", str(ds), str(versions[0]), str(versions[-1]))
    for v in versions:
        splits = json.loads((ds / "versions" / f"v{v:06d}.json").read_text())["splits"]
        run("validate", str(ds), "--version", str(v), *(["--split", "main"] if "main" in splits else []))
    run("validate", str(merged), "--deep")
    print(f"\nworkdir: {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
