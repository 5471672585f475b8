"""Where HandTouch's training configs (`configs/*.toml`) live.

They sit at the repository root (`configs/`) for users to read and copy; a
built wheel carries them as package data (`handtouch/_data/configs`, copied
by setup.py). `config_file` looks in the package data first, then in the
checkout beside the package (editable installs, running from source).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from htdata.errors import ArgumentError

PACKAGE_DATA = "_data"          # handtouch/_data/configs in a wheel (setup.py)
CHECKOUT_CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def config_dirs() -> list[Path]:
    """Folders searched for configs, in lookup order (only those that exist)."""
    candidates = [Path(str(resources.files("handtouch") / PACKAGE_DATA / "configs")), CHECKOUT_CONFIGS]
    return [p for p in candidates if p.is_dir()]


def available_configs() -> list[str]:
    """Names (without .toml) of every config found in the searched folders."""
    return sorted({p.stem for d in config_dirs() for p in d.glob("*.toml")})


def config_file(name: str) -> Path:
    """Path of the shipped config `name` ("smoke" or "smoke.toml").

    Raises FileNotFoundError listing the configs that exist.
    """
    filename = name if name.endswith(".toml") else f"{name}.toml"
    if Path(filename).name != filename:
        raise ArgumentError(f"config name {name!r} must be a bare name such as 'smoke', not a path")
    for folder in config_dirs():
        path = folder / filename
        if path.is_file():
            return path
    looked = ", ".join(str(d) for d in config_dirs()) or "no configs folder found"
    raise FileNotFoundError(f"config {name!r} not found (looked in {looked}); "
                            f"available: {', '.join(available_configs()) or 'none'}")
