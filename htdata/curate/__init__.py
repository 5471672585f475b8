"""Curation: every command that makes a new version out of an existing one.

    split.py          `htdata split`: hold out tasks, split the rest by episode
    splitversions.py  commit a split as a new version
    edit.py           `htdata rm` / `htdata trim`: plan, then re-pack the touched units
    idle.py           `htdata trim --idle`: the idle head and tail of each episode
    merge.py          `htdata merge`: several datasets into one
    gc.py             `htdata gc`: delete what no kept version lists
    renormalise.py    `htdata renormalise`: new normalisation from the stored raw rows
    upgrade.py        `htdata upgrade`: the current version again in today's format

Re-packing (copying committed samples into new shards) is htdata/write/repack.py, shared with ingest;
the split rule is htdata/store/splitrule.py (validate and the trainer apply it too, and import no writer).

May import: the writers' shared layer (htdata.write), the store, reading, inspection (the stats cache),
the glove model, the format and the base modules. Never ingest (its sibling), validate, the
benchmarks or the commands.

Imports inside functions: `__getattr__` hands on the names of the old one-module
`htdata.curate` (now edit.py), with a DeprecationWarning, until htdata/_moved.py's
REMOVED_IN, importing edit.py only when asked.
"""


def __getattr__(name: str):
    from htdata._moved import moved_name  # lazy: see the docstring

    return moved_name(__name__, name)
