"""A built wheel carries schemas/, pipelines/ and configs/, and the installed package finds them.

The full proof (fresh venv, `pip install` of the wheel, sample -> ingest ->
split -> validate from outside the checkout) is `make install-check`, run by
CI after the tests. Here: the wheel's contents, the lookup order of
htdata.resources / handtouch.resources with the wheel unpacked on
PYTHONPATH, the HTDATA_ROOT override, and the errors when something is missing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from handtouch.resources import available_configs, config_file

ROOT = Path(__file__).resolve().parents[2]
DATA = {"schemas": "htdata/_data/schemas", "pipelines": "htdata/_data/pipelines",
        "configs": "handtouch/_data/configs"}
SOURCES = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "htdata", "handtouch", *DATA)


def _run(args: list[str], cwd: Path, env: dict | None = None) -> str:
    proc = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"{args}: {proc.stdout}\n{proc.stderr}"
    return proc.stdout


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The project's wheel, built from a copy of the sources (the checkout gets no build/ folder)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(path, src / name)
    # No build isolation: this venv's setuptools, no index needed (make install-check uses isolation).
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(tmp / "dist"),
          str(src)], cwd=tmp)
    (found,) = (tmp / "dist").glob("htdata-*.whl")
    return found


def test_wheel_carries_every_data_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder, target in DATA.items():
        files = [p for p in (ROOT / folder).rglob("*") if p.is_file()]
        assert files, folder
        for p in files:
            assert f"{target}/{p.relative_to(ROOT / folder).as_posix()}" in names, (folder, p)
    assert not any(n.startswith(("schemas/", "pipelines/", "configs/")) for n in names)   # no top-level clutter


def test_unpacked_wheel_resolves_its_own_data_from_another_directory(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "HTDATA_ROOT"}
    env["PYTHONPATH"] = str(site)
    code = ("import htdata.resources as r, handtouch.resources as h; from htdata.glove.layouts import list_layouts; "
            "print(r.SCHEMAS_DIR); print(r.PIPELINES_DIR); print(h.config_file('smoke')); print(list_layouts())")
    out = _run([sys.executable, "-c", code], cwd=elsewhere, env=env).splitlines()
    schemas, pipelines, smoke, layouts = out
    assert Path(schemas) == site / "htdata" / "_data" / "schemas"
    assert Path(pipelines) == site / "htdata" / "_data" / "pipelines"
    assert Path(smoke) == site / "handtouch" / "_data" / "configs" / "smoke.toml"
    assert "opentouch_right_16x16" in layouts


def test_htdata_root_overrides_and_names_a_missing_folder(tmp_path):
    copy = tmp_path / "mine"
    shutil.copytree(ROOT / "schemas", copy / "schemas")
    shutil.copytree(ROOT / "pipelines", copy / "pipelines")
    code = "import htdata.resources as r; print(r.SCHEMAS_DIR); print(r.PIPELINES_DIR)"
    env = {**os.environ, "HTDATA_ROOT": str(copy)}
    assert _run([sys.executable, "-c", code], cwd=tmp_path, env=env).split() == [
        str(copy / "schemas"), str(copy / "pipelines")]
    shutil.rmtree(copy / "pipelines")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode != 0
    assert f"HTDATA_ROOT={copy}: no pipelines/ folder there" in proc.stderr


def test_config_file_finds_shipped_configs_and_lists_them_on_a_miss():
    assert config_file("smoke") == config_file("smoke.toml")
    assert config_file("smoke").read_text() == (ROOT / "configs" / "smoke.toml").read_text()
    assert {"smoke", "full"} <= set(available_configs())
    with pytest.raises(FileNotFoundError, match=r"config 'nope' not found .*available: .*full.*smoke"):
        config_file("nope")
    with pytest.raises(ValueError, match="bare name"):
        config_file("../configs/smoke")
