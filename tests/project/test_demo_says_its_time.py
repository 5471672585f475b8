"""`make demo` says how long it takes before it starts, and its install is not silent for minutes."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_demo_prints_its_expected_time_before_any_work():
    # -n: what make would run, in order, without running it (.venv exists or not: setup's recipe is listed
    # either way when it is out of date; the intro comes first regardless)
    # a clean environment: under `make test` the parent make's MAKEFLAGS / MAKELEVEL would add its own lines
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
    out = subprocess.run(["make", "--no-print-directory", "-n", "-B", "demo"], cwd=ROOT, capture_output=True,
                         text=True, check=True, env=env).stdout
    first = out.splitlines()[0]
    assert first.startswith("echo") and re.search(r"\d+-?\d* min", first), first


def test_setup_shows_install_progress():
    recipe = (ROOT / "Makefile").read_text().split("$(VENV)/.installed:", 1)[1].split("\n\n", 1)[0]
    install = [line for line in recipe.splitlines() if "pip install" in line and "-e" in line]
    assert install and all(" -q " not in line for line in install), install
