"""The smoke's data: the sample corpus, its dataset, the split and the split's leak check.

The split holds out two tasks whole (`htdata split --ood-task` twice):

    OOD_TASK     the held-out task the gate is on: cup_grasp, power_grasp's touch, support and hand
                 shape on a new object (htdata.synthetic.tasks.TWINS). The paper's OOD is new
                 tasks, not new physics: a held-out task shares its touch with a training task.
    STRESS_TASK  palm_push, reported as a stress test: no training task touches with the palm alone
                 on an open hand, so nothing the camera sees in training looks like it.

`split_leak_check` runs the split validator's record checks on the split (held-out tasks only in
ood, every episode in one part, the counts): a leak would raise held-out scores, so no learned check
can catch it; it is structural and required.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from htdata.format.table import MANIFEST_FILE
from htdata.read.metadata import DatasetMetadata
from htdata.resources import PIPELINES_DIR
from htdata.synthetic.corpus import FORMATS as SAMPLE_FORMATS
from htdata.synthetic.corpus import CorpusConfig, corpus_complete
from htdata.validate import check_split_records

RAW_FORMATS = SAMPLE_FORMATS            # every source format the sample corpus writes (an adapter without sample data is skipped)
SPLIT_NAME = "smoke"
OOD_TASK = "cup_grasp"
STRESS_TASK = "palm_push"
SCALE = "small"


def htdata(*args: str) -> None:
    """Run an htdata command in a child process; fail loudly with the command line."""
    cmd = [sys.executable, "-m", "htdata.cli", *args]
    print("+ htdata " + " ".join(args), flush=True)
    rc = subprocess.run(cmd).returncode
    if rc != 0:
        raise SystemExit(f"smoke: `htdata {' '.join(args)}` failed with exit code {rc}")


# The broken pipelines the smoke must catch, each a control corpus of `htdata sample` (the flag that
# writes it) and what must fail on it (handtouch.smokechecks.verdict).
BROKEN = {"mispaired": "--mispair-rgb", "lagged": "--rgb-lag-frames", "reversed": "--reverse-rgb"}
LAG_FRAMES = 6     # the lagged control's video lag: 0.2 s at 30 fps, 3x the lag check's tolerance


def _corpus(raw: Path, seed: int, broken: str | None, lag_frames: int) -> CorpusConfig:
    return CorpusConfig(out=raw, seed=seed, scale=SCALE, progress=False, mispair_rgb=broken == "mispaired",
                        rgb_lag_frames=lag_frames if broken == "lagged" else 0, reverse_rgb=broken == "reversed")


def raw_complete(raw: Path, seed: int, broken: str | None = None, lag_frames: int = LAG_FRAMES) -> bool:
    """True when `raw` holds the finished sample corpus `ensure_raw` would write."""
    return corpus_complete(_corpus(raw, seed, broken, lag_frames))


def ensure_raw(raw: Path, seed: int, broken: str | None = None, lag_frames: int = LAG_FRAMES) -> None:
    """The small sample corpus of `seed` at `raw`: kept if finished (the Makefile's too), else written.
    broken (BROKEN): a control corpus: every episode's video shows another episode ("mispaired"), lags
    its glove by `lag_frames` frames ("lagged") or plays backwards ("reversed")."""
    extra = []
    if broken:
        extra = [BROKEN[broken], str(lag_frames)] if broken == "lagged" else [BROKEN[broken]]
    htdata("sample", str(raw), "--seed", str(seed), "--scale", SCALE, "--quiet", "--reuse", *extra)


def ensure_dataset(raw: Path, dataset: Path, workers: int) -> None:
    if (dataset / MANIFEST_FILE).is_file():
        print(f"smoke: dataset present at {dataset}", flush=True)
        return
    pipes = []
    for f in RAW_FORMATS:
        pipes += ["--pipeline", f"{PIPELINES_DIR / (f + '.toml')}={raw / f}"]
    htdata("ingest", "--workers", str(workers), "--quiet", *pipes, str(dataset))


def make_split(dataset: Path, ood_tasks: list[str], seed: int) -> None:
    """Split SPLIT_NAME of `dataset` with `ood_tasks` held out whole (`htdata split`)."""
    tasks = DatasetMetadata(dataset).tasks
    missing = [t for t in ood_tasks if t not in tasks]
    if missing:
        raise SystemExit(f"smoke: held-out task(s) {missing} not in {dataset} (tasks: {tasks}); a dataset "
                         "built from an older sample corpus lacks them: delete it (and its raw corpus) and rerun")
    held = [a for t in ood_tasks for a in ("--ood-task", t)]
    htdata("split", str(dataset), *held, "--seed", str(seed), "--name", SPLIT_NAME, "--force")


def split_leak_check(dataset: Path, split: str = SPLIT_NAME) -> dict:
    """The smoke's check of the split validator's record checks (module docstring), required."""
    res = check_split_records(dataset, split)
    leaks = res["failure_counts"].get("ood_task_leak", 0)
    return {"check": f"split validator on split {split}: no held-out (ood) task leak, no other split failure",
            "value": res["failure_count"], "limit": 0, "ok": res["failure_count"] == 0, "required": True,
            "ood_task_leaks": leaks, "failures": [f["message"] for f in res["failures"][:10]]}


def toml_str(value: str) -> str:
    return json.dumps(str(value))   # a JSON string is a valid TOML basic string
