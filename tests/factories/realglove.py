"""The real raw-count glove recordings beside the repository (../shared/real_glove), for the tests that name them.

The toolkit never reads that folder on its own; tests take it by this explicit path and skip, saying so,
in a clone without it (CI has it).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# HTDATA_REAL_GLOVE names the folder where the checkout has no ../shared beside it (a worktree elsewhere)
REAL_GLOVE = Path(os.environ.get("HTDATA_REAL_GLOVE")
                  or Path(__file__).resolve().parents[2].parent / "shared" / "real_glove")


def real_glove_dir() -> Path:
    """The folder, or a pytest skip naming where it was looked for."""
    if not (REAL_GLOVE / "clips" / "manifest.jsonl").is_file():
        pytest.skip(f"no real glove recordings at {REAL_GLOVE} (../shared/real_glove beside the repository)")
    return REAL_GLOVE
