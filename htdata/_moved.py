"""Old module names of the flat htdata root, kept importable for one release (deprecated).

Round three regrouped htdata by concern (htdata/__init__.py). Code written
against the old names (`from htdata.reader import DatasetReader`,
`import htdata.torchdata`) keeps working: `install()` puts a finder on
sys.meta_path that answers an old name with the module at its new place (the
same module object, so monkeypatching and isinstance checks agree), and warns
once with a DeprecationWarning naming the new place. Remove in htdata 0.3.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

# old name -> new name (a package's submodules follow it: htdata.adapters.base -> htdata.source.adapters.base)
MOVED = {
    "htdata.adapters": "htdata.source.adapters",
    "htdata.sync": "htdata.source.sync", "htdata.lag": "htdata.source.lag", "htdata.rgb": "htdata.source.rgb",
    "htdata.layouts": "htdata.glove.layouts", "htdata.normalise": "htdata.glove.normalise",
    "htdata.calibration": "htdata.glove.calibration", "htdata.rasterise": "htdata.glove.rasterise",
    "htdata.health": "htdata.glove.health",
    "htdata.codec": "htdata.format.codec", "htdata.codecrule": "htdata.glove.codecrule",
    "htdata.shardio": "htdata.format.shardio",
    "htdata.manifest": "htdata.store.manifest", "htdata.versions": "htdata.store.versions",
    "htdata.snapshot": "htdata.store.snapshot", "htdata.parts": "htdata.store.parts",
    "htdata.lock": "htdata.store.lock", "htdata.fsutil": "htdata.store.fsutil",
    "htdata.storage": "htdata.store.storage", "htdata.remote": "htdata.store.remote",
    "htdata.split": "htdata.curate.split", "htdata.splitversions": "htdata.curate.splitversions",
    "htdata.merge": "htdata.curate.merge", "htdata.gc": "htdata.curate.gc",
    "htdata.repack": "htdata.curate.repack", "htdata.renormalise": "htdata.curate.renormalise",
    "htdata.reader": "htdata.read.reader", "htdata.torchdata": "htdata.read.torchdata",
    "htdata.torchglove": "htdata.read.torchglove", "htdata.rawstream": "htdata.read.rawstream",
    "htdata.keys": "htdata.read.keys",
    "htdata.stats": "htdata.inspect.stats", "htdata.episodestats": "htdata.inspect.episodestats",
    "htdata.healthmap": "htdata.inspect.healthmap", "htdata.idle": "htdata.curate.idle",
    "htdata.card": "htdata.inspect.card", "htdata.preview": "htdata.inspect.preview",
    "htdata.executors": "htdata.ingest.executors", "htdata.bench": "htdata.benchmarks.suite",
}
# htdata.format and htdata.curate kept their names as packages: their __init__ hands the old names on.


def new_name(fullname: str) -> str | None:
    """The module that old name `fullname` now is, or None when the name did not move."""
    for old, new in MOVED.items():
        if fullname == old or fullname.startswith(old + "."):
            return new + fullname[len(old):]
    return None


class _Alias(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        warnings.warn(f"{spec.name} is deprecated: it moved to {self.target}", DeprecationWarning, stacklevel=3)
        module = importlib.import_module(self.target)
        self.real_spec = module.__spec__
        return module

    def exec_module(self, module):
        module.__spec__ = self.real_spec   # the import system set the old name's spec: give the real one back


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        new = new_name(fullname)
        return None if new is None else importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())
