"""Where the project's data files (schemas, layouts, pipelines) live.

They are plain files at the repository root so users can read and edit them;
the package is installed editable (`make setup`). HTDATA_ROOT overrides.
"""

from __future__ import annotations

import json
import os
from functools import lru_cache
from pathlib import Path

PROJECT_ROOT = Path(os.environ.get("HTDATA_ROOT", Path(__file__).resolve().parents[1]))
SCHEMAS_DIR = PROJECT_ROOT / "schemas"
LAYOUTS_DIR = SCHEMAS_DIR / "layouts"
PIPELINES_DIR = PROJECT_ROOT / "pipelines"


@lru_cache(maxsize=None)
def load_schema(name: str) -> dict:
    """Load `schemas/<name>.schema.json` (name without suffix)."""
    path = SCHEMAS_DIR / f"{name}.schema.json"
    if not path.is_file():
        raise FileNotFoundError(f"schema {name!r} not found at {path}")
    return json.loads(path.read_text())


def validate_json(instance, schema_name: str, where: str = "") -> None:
    """Validate `instance` against a project schema; raise ValueError naming `where`."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(load_schema(schema_name))
    errors = sorted(validator.iter_errors(instance), key=lambda e: list(e.path))
    if errors:
        e = errors[0]
        loc = "/".join(str(p) for p in e.path) or "<root>"
        more = f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ValueError(f"{where or schema_name}: {loc}: {e.message}{more}")
