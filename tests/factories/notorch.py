"""A Python without torch, for the checks of what an install without the torch extras does.

`without_torch(folder)` writes a `sitecustomize.py` into `folder` that makes every `import torch` (and
`torch.*`) fail as a missing package does; a subprocess with `folder` first on PYTHONPATH runs as if
torch were not installed, whatever the venv holds.
"""

from __future__ import annotations

import os
from pathlib import Path

BLOCKER = '''import sys


class _NoTorch:
    """Import hook: torch is not installed here."""

    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


sys.meta_path.insert(0, _NoTorch())
'''


def without_torch(folder: Path, root: Path) -> dict[str, str]:
    """The environment of a subprocess that imports `root`'s htdata and finds no torch."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(BLOCKER)
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(folder), str(root)])}
