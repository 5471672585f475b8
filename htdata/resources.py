"""Where the project's data files (schemas, layouts, pipelines) live.

They are plain files at the repository root (`schemas/`, `pipelines/`) so
users read and edit them there; a built wheel carries copies as package data
(`htdata/_data/`, copied by setup.py). Lookup order, first existing folder wins:

1. `$HTDATA_ROOT/schemas`, `$HTDATA_ROOT/pipelines` when the environment
   variable HTDATA_ROOT names a folder holding them (a checkout or a copy
   with edited schemas/pipelines; it must hold both);
2. the installed package data (`importlib.resources`: `htdata/_data/...`);
3. the checkout beside the package (editable installs, running from source).
"""

from __future__ import annotations

import json
import os
from functools import lru_cache
from importlib import resources
from pathlib import Path

ROOT_ENV = "HTDATA_ROOT"
PACKAGE_DATA = "_data"          # htdata/_data/{schemas,pipelines} in a wheel (setup.py)
CHECKOUT_ROOT = Path(__file__).resolve().parents[1]


def data_dir(name: str) -> Path:
    """The folder `name` ("schemas" or "pipelines"), by the lookup order above."""
    override = os.environ.get(ROOT_ENV)
    if override:
        path = Path(override) / name
        if not path.is_dir():
            raise FileNotFoundError(f"{ROOT_ENV}={override}: no {name}/ folder there ({path})")
        return path
    candidates = [Path(str(resources.files("htdata") / PACKAGE_DATA / name)), CHECKOUT_ROOT / name]
    for path in candidates:
        if path.is_dir():
            return path
    looked = ", ".join(str(p) for p in candidates)
    raise FileNotFoundError(f"htdata data folder {name}/ not found (looked at {looked}); "
                            f"reinstall the package or set {ROOT_ENV} to a folder holding {name}/")


SCHEMAS_DIR = data_dir("schemas")
LAYOUTS_DIR = SCHEMAS_DIR / "layouts"
PIPELINES_DIR = data_dir("pipelines")


@lru_cache(maxsize=None)
def load_schema(name: str) -> dict:
    """Load `schemas/<name>.schema.json` (name without suffix)."""
    path = SCHEMAS_DIR / f"{name}.schema.json"
    if not path.is_file():
        raise FileNotFoundError(f"schema {name!r} not found at {path}")
    return json.loads(path.read_text())


@lru_cache(maxsize=None)
def _validator(schema_name: str):
    """One validator per schema per process: building one costs more than most validations."""
    import jsonschema

    return jsonschema.Draft202012Validator(load_schema(schema_name))


def validate_json(instance, schema_name: str, where: str = "", error: type[ValueError] = ValueError) -> None:
    """Validate `instance` against a project schema; raise `error` naming `where`.

    `error` says whose mistake a failure is: ConfigError for a document the user wrote (a pipeline,
    a layout), DatasetError for a record read from a dataset; the default suits documents our own
    code built, where a failure is a bug."""
    validator = _validator(schema_name)
    errors = sorted(validator.iter_errors(instance), key=lambda e: list(e.path))
    if errors:
        e = errors[0]
        loc = "/".join(str(p) for p in e.path) or "<root>"
        more = f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""
        raise error(f"{where or schema_name}: {loc}: {e.message}{more}")
