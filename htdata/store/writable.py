"""The folders of a dataset a writer writes or deletes in are the dataset's own, never symlinks out of it.

A stranger's dataset may hold `shards/`, `segments/`, `.work/`, `reports/`, `stats/`, `layouts/`,
`versions/` or `splits/` as a symlink to a folder elsewhere: an append would then delete unrelated `shard-*.tar` /
`unit-*.json` files there and write its shards there, validate and stats their reports and caches.
`check_writable_folders` refuses such a dataset before anything is written (one line naming the link);
every writer calls it through `store.lock.WriterLock`, `htdata validate` before it writes its report,
the stats cache (htdata/inspect/stats.py) reads and writes nothing through one. Readers read through a
symlinked folder as before (a shard's own symlink is judged by htdata/store/confine.py).
"""

from __future__ import annotations

import os
from pathlib import Path

from htdata.errors import DatasetError
from htdata.format.table import LAYOUTS_DIR, REPORTS_DIR, SEGMENTS_DIR, SHARDS_DIR, SPLITS_DIR, STATS_DIR, WORK_DIR
from htdata.store.versions import VERSIONS_DIR

WRITER_FOLDERS = (SHARDS_DIR, SEGMENTS_DIR, WORK_DIR, REPORTS_DIR, STATS_DIR, LAYOUTS_DIR, VERSIONS_DIR, SPLITS_DIR)


class SymlinkedFolder(DatasetError):
    """A folder of a dataset that a writer would write or delete in is a symlink."""


def symlinked_folder(root, name: str) -> str | None:
    """The one-line refusal for DATASET/`name` when it is a symlink (None: it is not)."""
    path = Path(root) / name
    if not path.is_symlink():
        return None
    try:
        target = os.readlink(path)
    except OSError:
        target = "?"
    return (f"{path} is a symlink (to {target}): htdata writes and deletes nothing through a symlinked folder of "
            f"a dataset; replace it by a real folder holding what it points to, then run the command again")


def check_writable_folders(root, names: tuple[str, ...] = WRITER_FOLDERS) -> None:
    """Refuse (SymlinkedFolder, one line naming it) a dataset whose folder in `names` is a symlink."""
    for name in names:
        why = symlinked_folder(root, name)
        if why:
            raise SymlinkedFolder(why)
