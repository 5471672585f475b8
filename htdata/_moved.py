"""Old names of htdata, kept importable until `REMOVED_IN` (deprecated): the one shim mechanism.

Round three regrouped htdata by concern (htdata/__init__.py). Code written
against the old names keeps working, and every old name warns with a
DeprecationWarning naming its new place:

- old modules (`from htdata.reader import DatasetReader`, `import htdata.torchdata`):
  `install()` puts a finder on sys.meta_path that answers an old name with the
  module at its new place (the same module object, so monkeypatching and
  isinstance checks agree);
- old names of a package or module that kept its name (`from htdata.format import SHARDS_DIR`,
  `htdata.curate.rm_episodes`, `from htdata.format.table import CANVAS`): its `__getattr__` calls
  `moved_name`; a module never re-exports a moved name silently (tests/project/test_layering.py);
- old keyword arguments (`TactileFrameDataset(root, map_source="auto")`): the function is
  wrapped by `renamed_keyword`, which hands the value on under its new name;
- old keywords that one options object holds now (`TactileFrameDataset(root, split="main")`):
  `folded_keywords` builds the object from them and hands it on.

`REMOVED_IN` is the one place that says when all of it goes;
tests/project/test_moved.py fails once htdata's version reaches it, so the shim cannot
outlive its promise unnoticed.
"""

from __future__ import annotations

import functools
import importlib
import importlib.abc
import importlib.util
import inspect
import sys
import warnings

# The htdata version that deletes this module and the `__getattr__` hand-offs of the modules in MOVED_NAMES.
REMOVED_IN = (0, 3)

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
    "htdata.repack": "htdata.write.repack", "htdata.renormalise": "htdata.curate.renormalise",
    "htdata.reader": "htdata.read.reader", "htdata.torchdata": "htdata.read.torchdata",
    "htdata.torchglove": "htdata.read.torchglove", "htdata.rawstream": "htdata.read.rawstream",
    "htdata.keys": "htdata.read.keys",
    "htdata.stats": "htdata.inspect.stats", "htdata.episodestats": "htdata.inspect.episodestats",
    "htdata.healthmap": "htdata.inspect.healthmap", "htdata.idle": "htdata.curate.idle",
    "htdata.card": "htdata.inspect.card", "htdata.preview": "htdata.inspect.preview",
    "htdata.executors": "htdata.ingest.executors", "htdata.bench": "htdata.benchmarks.suite",
    # round four (the house pass): the writers' shared layer, ingest's configuration, the synthetic corpus
    "htdata.curate.repack": "htdata.write.repack", "htdata.pipeline": "htdata.ingest.pipeline",
    "htdata.sample": "htdata.synthetic",
    # the third house pass: the split rule below the writers (validate and handtouch apply it)
    "htdata.curate.splitrule": "htdata.store.splitrule",
}
# Modules that kept their names: an attribute they no longer have is looked up in this module (or these).
MOVED_NAMES = {
    "htdata.format": "htdata.format.table",   # the format was one module: its names are the table's now
    "htdata.curate": "htdata.curate.edit",    # `htdata.curate` was one module: rm / trim are edit.py now
    # the adapter contract's helpers, each in a module of its own now
    "htdata.source.adapters.base": ("htdata.source.adapters.discovery", "htdata.source.adapters.sourcetree",
                                    "htdata.source.adapters.params", "htdata.source.adapters.streamchecks"),
    # the third house pass: the crash-safe writes went below every package (htdata/fileio.py); the store kept sha256_file
    "htdata.store.fsutil": "htdata.fileio",
    # the fourth house pass: names that a module re-exported silently from where they moved
    "htdata.format.table": "htdata.format.canvas",
    "htdata.glove.layouts": "htdata.glove.canonical",
    "htdata.source.lag": "htdata.source.syncsettings",
    "htdata.ingest.pipeline": "htdata.settings",
    "htdata.curate.edit": "htdata.store.episodeids",
    "htdata.curate.split": ("htdata.store.splitrule", "htdata.store.splitfiles"),
    "htdata.read.reader": "htdata.store.splitfiles",
    "htdata.read.torchdata": ("htdata.read.itemoptions", "htdata.read.torchitems"),
    # the tactile value rule and the EXR codec, a module of their own beside the registry
    "htdata.format.codec": "htdata.format.tactilecodec",
    # the normaliser's settings, a module of their own beside the normaliser
    "htdata.glove.normalise": "htdata.glove.normaliseconfig",
}
# old name -> new name, for names that were renamed as they moved (looked up before the name itself)
RENAMED = {("htdata.source.adapters.base", "check_adapter_params"): "check_declared_params",
           ("htdata.read.torchdata", "_ItemBuilder"): "ItemBuilder"}


def new_name(fullname: str) -> str | None:
    """The module that old name `fullname` now is, or None when the name did not move."""
    for old, new in MOVED.items():
        if fullname == old or fullname.startswith(old + "."):
            return new + fullname[len(old):]
    return None


def moved_name(package: str, name: str):
    """`package.name` from the module it moved to (MOVED_NAMES), with a DeprecationWarning.

    For a module-level `__getattr__`: AttributeError, as Python expects, when the old module
    never had that name either.
    """
    targets = MOVED_NAMES[package]
    new = RENAMED.get((package, name), name)
    for target in (targets,) if isinstance(targets, str) else targets:
        module = importlib.import_module(target)
        if not name.startswith("__") and hasattr(module, new):
            warnings.warn(f"{package}.{name} is deprecated: it moved to {module.__name__}.{new}",
                          DeprecationWarning, stacklevel=3)
            return getattr(module, new)
    raise AttributeError(f"module {package!r} has no attribute {name!r}")


def renamed_keyword(old: str, new: str, values: dict | None = None):
    """Decorator: the wrapped function still takes `old=` (deprecated), handed on as `new=` with a DeprecationWarning.

    Args:
        old: the keyword's old name.
        new: its name now (a parameter of the wrapped function).
        values: old values that have new words ({"auto": "best"}); any other value is handed on as given.

    A call giving both names is a TypeError, as Python's own for a keyword given twice.
    """
    words = dict(values or {})

    def wrap(fn):
        name = fn.__qualname__.removesuffix(".__init__")

        @functools.wraps(fn)
        def call(*args, **kwargs):
            if old in kwargs:
                if new in kwargs:
                    raise TypeError(f"{name}() got both {old}= and {new}= (the old and the new name of one argument)")
                value = kwargs.pop(old)
                kwargs[new] = words.get(value, value) if isinstance(value, str) else value
                warnings.warn(f"{name}({old}={value!r}) is deprecated: write {new}={kwargs[new]!r} "
                              f"({old}= goes in htdata {'.'.join(map(str, REMOVED_IN))})",
                              DeprecationWarning, stacklevel=2)
            return fn(*args, **kwargs)
        return call
    return wrap


def folded_keywords(into: str, fold, names: tuple[str, ...], positional: tuple[str, ...] = ()):
    """Decorator: the wrapped function's old keywords `names` (deprecated) reach it as one `into=` object.

    Args:
        into: the keyword-only parameter that holds them now (an options object).
        fold: `fold(into_value_or_None, {old keyword: value})` -> the object handed on as `into=`; it raises
            when the two cannot be combined.
        names: the old keywords.
        positional: the old signature's parameters after the ones the function still takes by position, in
            order: a call giving them by position is read as giving them by keyword (then folded, or handed on).

    Returns:
        The decorator. A call with none of the old keywords runs the function unchanged, without a warning.
    """
    def wrap(fn):
        name = fn.__qualname__.removesuffix(".__init__")
        kept = sum(p.kind is p.POSITIONAL_OR_KEYWORD for p in inspect.signature(fn).parameters.values())

        @functools.wraps(fn)
        def call(*args, **kwargs):
            if len(args) > kept:   # the old signature took these by position
                if len(args) > kept + len(positional):
                    raise TypeError(f"{name}() takes at most {kept + len(positional)} positional arguments")
                for key, value in zip(positional, args[kept:]):
                    if key in kwargs:
                        raise TypeError(f"{name}() got multiple values for argument {key!r}")
                    kwargs[key] = value
                args = args[:kept]
            given = {k: kwargs.pop(k) for k in names if k in kwargs}
            if given:
                kwargs[into] = fold(kwargs.get(into), given)
                written = ", ".join(f"{k}={v!r}" for k, v in given.items())
                warnings.warn(f"{name}({written}) is deprecated: pass {into}={type(kwargs[into]).__name__}"
                              f"({written}) (the keywords go in htdata {'.'.join(map(str, REMOVED_IN))})",
                              DeprecationWarning, stacklevel=2)
            return fn(*args, **kwargs)
        return call
    return wrap


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
