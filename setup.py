"""Build hook: ship the repository's data folders inside the wheel.

`schemas/`, `pipelines/` (read by htdata) and `configs/` (read by handtouch)
stay at the repository root, where users read and edit them; a built wheel
carries copies as package data so an installed (non-editable) htdata works
from any directory:

    schemas/   -> htdata/_data/schemas
    pipelines/ -> htdata/_data/pipelines
    configs/   -> handtouch/_data/configs

`htdata.resources` and `handtouch.resources` look there first and fall back
to the checkout (editable installs skip the copy and read the folders in
place). Everything else about the project lives in pyproject.toml;
MANIFEST.in puts the three folders in the sdist so a wheel built from it
has them too. `make install-check` proves the result.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
# Keep in step with htdata/resources.py (PACKAGE_DATA) and handtouch/resources.py.
DATA_FOLDERS = {
    "schemas": "htdata/_data/schemas",
    "pipelines": "htdata/_data/pipelines",
    "configs": "handtouch/_data/configs",
}


class BuildPyWithData(build_py):
    """build_py, then copy each data folder into the built package tree."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install reads the folders in the checkout
        for source, target in DATA_FOLDERS.items():
            src = ROOT / source
            if not src.is_dir():
                raise FileNotFoundError(f"setup.py: data folder {src} is missing; the wheel would not work")
            dst = Path(self.build_lib) / target
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", ".*"))


setup(cmdclass={"build_py": BuildPyWithData})
