"""The one owner of a new version's transaction: lock -> parent -> units -> parts -> commit, or clean up.

Every writer of a new version (ingest, split, rm, trim, merge, renormalise) does the same steps, in
this order, through `NewVersion`:

1. take the dataset's writer lock (htdata/store/lock.py: one writer; a symlinked writers' folder is
   refused before anything is written, htdata/store/writable.py);
2. open the parent: the current version (`parent="current"`; an ingest's first run has none,
   `"optional"`; a merge writes a new dataset, `"none"`);
3. number new work units from the parent's `next_unit` (shard names stay unique across versions);
   the first write clears the shards of units at or past it that no version lists (an interrupted
   write's leftovers), so a re-run takes the numbers a run that never crashed would;
4. carry the parent's parts, or re-pack the touched ones into new units (`repack`, byte for byte):
   one walk, `carry_or_repack`, in which the writer only says what becomes of each part;
5. `commit`: htdata/store/snapshot.py `commit_parts`, the version file linked into place last.

A write killed after its version file was linked but before dataset.json was rewritten has
committed (the version file is the commit; dataset.json its cache). The next write finishes it
when it takes the lock: the pointer is rewritten from the newest version file, and a re-run of the
very command that made that version (its change record's command line) ends there with
`AlreadyCommitted` (the CLI: one line, rc 0) instead of failing on a change already made. (That
pointer repair is the one write a `--dry-run` may make: it changes no version, only the cache.)

Any failure before the commit (an exception, Ctrl-C) deletes the units this write made, so a failed
write leaves the dataset as it found it; a kill -9 leaves them to the next write's step 3. Nothing
happens before the first write: a `--dry-run` plans under the lock and writes nothing. A resumable
writer (`resumable=True`: the ingest's finished units, a merge's placed shards) keeps what it wrote
for its re-run instead, and clears its own leftovers its own way (htdata/ingest/workdir.py,
htdata/curate/merge.py).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from htdata.errors import AlreadyCommitted
from htdata.format.table import MANIFEST_FILE
from htdata.read.reader import DatasetReader
from htdata.store.lock import WriterLock
from htdata.store.parts import Part
from htdata.store.snapshot import Snapshot, SplitMaker, commit_parts, current_snapshot, open_snapshot
from htdata.store.versions import list_versions, restore_pointer, version_manifest_file
from htdata.write.repack import (
    KeptEpisode,
    SampleRewrite,
    clear_uncommitted,
    clear_unit,
    repack_unit,
    samples_per_shard_of,
)

PARENTS = ("current", "optional", "none")


class NewVersion:
    """`with NewVersion(root, command) as nv:` plan on `nv.parent`, then `nv.repack(...)` / `nv.commit(parts)`.

    Args:
        root: the dataset folder the new version goes to.
        command: the command line recorded in the lock and in the version's change record.
        parent: "current" (the dataset's current version; not a dataset is an error), "optional" (None
            when `root` holds no committed dataset: a first ingest) or "none" (a new dataset: merge's OUT).
        first_unit: the first unit number of this write (default: the parent's `next_unit`, 0 without one).
        resumable: keep what this write made when it fails, and clear no leftovers (its re-run resumes them).
        new_units: False for a version made of the parent's parts as they are (`htdata split`): it takes no
            unit and clears no leftover (an interrupted ingest's finished units stay for its re-run).
    """

    def __init__(self, root: str | os.PathLike, command: str, parent: str = "current",
                 first_unit: int | None = None, resumable: bool = False, new_units: bool = True):
        if parent not in PARENTS:
            raise ValueError(f"parent must be one of {PARENTS}, got {parent!r}")
        self.root, self.command, self.resumable, self.new_units = Path(root), command, resumable, new_units
        self._parent_mode, self._first = parent, first_unit
        self.lock = WriterLock(self.root, command)
        self.parent: Snapshot | None = None
        self.first_unit = self.unit = 0
        self.manifest: dict | None = None     # the committed version's, once committed
        self._writing = False
        self._reader: DatasetReader | None = None

    def __enter__(self) -> "NewVersion":
        self.lock.acquire()
        try:
            self._finish_interrupted_commit()
            if self._parent_mode == "current":
                self.parent = open_snapshot(self.root)
            elif self._parent_mode == "optional":
                self.parent = current_snapshot(self.root)
            start = self.parent.next_unit() if self.parent is not None else 0
            self.first_unit = self.unit = start if self._first is None else int(self._first)
        except BaseException:
            self.lock.release()
            raise
        return self

    def __exit__(self, kind, exc, tb) -> None:
        try:
            if kind is not None and self._writing and self.manifest is None and self.new_units and not self.resumable:
                self._clean_up()
        finally:
            if self._reader is not None:
                self._reader.close()
            self.lock.release()

    def _finish_interrupted_commit(self) -> None:
        """An earlier write linked its version file but was killed before the pointer: rewrite the pointer; when
        that write was this very command, raise AlreadyCommitted (see the module docstring)."""
        if self.resumable:   # an ingest or merge re-run resumes its own way (and says what it restored)
            return
        versions = list_versions(self.root)
        try:
            pointed = json.loads((self.root / MANIFEST_FILE).read_text()).get("version")
        except (OSError, ValueError, AttributeError):
            return    # a missing or damaged pointer is `htdata repair`'s (it names what it finds)
        # only the interrupted commit's state: the pointer behind a newer version file (a pointer
        # AHEAD of the newest file means a version file was deleted: that stays an error naming its fix)
        if not versions or not isinstance(pointed, int) or pointed >= versions[-1]:
            return
        if not restore_pointer(self.root, versions[-1]):
            return
        newest = json.loads((self.root / version_manifest_file(versions[-1])).read_text())
        if (newest.get("change") or {}).get("command") == self.command:
            raise AlreadyCommitted(self.root, versions[-1], self.command)

    @property
    def note(self) -> str | None:
        """What taking the lock had to say (a stale lock taken over), or None."""
        return self.lock.note

    def reader(self) -> DatasetReader:
        """A reader of the parent version (opened once, closed with the transaction)."""
        if self.parent is None:
            raise ValueError(f"{self.root}: this write has no parent version to read")
        if self._reader is None:
            self._reader = DatasetReader(self.parent.root, version=self.parent.version)
        return self._reader

    def _begin(self) -> None:
        """The first write: an interrupted write's leftovers (units >= first_unit no version lists) go."""
        if not self._writing:
            self._writing = True
            if self.new_units and not self.resumable:
                clear_uncommitted(self.root, self.first_unit)

    def take_unit(self) -> int:
        """The next free unit number, for this write's new shards."""
        if not self.new_units:
            raise ValueError(f"{self.root}: this write was opened with new_units=False")
        self._begin()
        unit, self.unit = self.unit, self.unit + 1
        return unit

    def skip_to(self, unit: int) -> None:
        """Units below `unit` are taken (an ingest's work units ran under their own numbers)."""
        self._begin()
        self.unit = max(self.unit, int(unit))

    def repack(self, reader: DatasetReader, kept: list[KeptEpisode], samples_per_shard: int,
               rewrite: SampleRewrite | None = None) -> Part:
        """`kept` episodes' samples (read through `reader`: the parent's, or another dataset's for a merge)
        copied into a new unit of this dataset, written whole (htdata/write/repack.py)."""
        unit = self.take_unit()
        clear_unit(self.root, unit)    # a resumed write's earlier try at this unit
        return repack_unit(reader, kept, unit, samples_per_shard, out_root=self.root, rewrite=rewrite)

    def carry_or_repack(self, choose: Callable[[Part], "Part | list[KeptEpisode] | None"],
                        parent: Snapshot | None = None, reader: DatasetReader | None = None,
                        rewrite: SampleRewrite | None = None) -> list[Part]:
        """The walk over a version's parts that every writer makes: each part in order, carried or re-packed.

        Args:
            choose: `choose(part)` says what of `part` the new version holds: a Part (carried: `part` itself,
                or one with new records over the same shards), a list of KeptEpisode (re-packed into a new unit
                of this write with the part's samples per shard, `repack`), or None / [] (nothing of it).
            parent: the version walked (default: this write's parent).
            reader: the reader the re-packed samples come from (default: `reader()`, this write's parent's;
                give one when `parent` is another dataset's version, as merge does).
            rewrite: changes samples while re-packing (htdata.curate.renormalise.Recalibration).

        Returns:
            The parts, in the walked version's order.

        Raises:
            ValueError: no version to walk (this write has no parent and none was given).
        """
        walked = self.parent if parent is None else parent
        if walked is None:
            raise ValueError(f"{self.root}: this write has no parent version to walk")
        parts = []
        for part in walked.parts():
            chosen = choose(part)
            if isinstance(chosen, Part):
                parts.append(chosen)
            elif chosen:
                parts.append(self.repack(reader or self.reader(), chosen, samples_per_shard_of(part),
                                         rewrite=rewrite))
        return parts

    def commit(self, parts: list[Part], fields: dict | None = None, splits: SplitMaker | None = None) -> dict:
        """Commit `parts` as the new version (htdata/store/snapshot.py `commit_parts`); returns its manifest.

        Args:
            parts: the new version's parts, carried or re-packed, in order.
            fields: manifest fields this write sets (sources, layouts, canonical, codec, calibrations).
            splits: the new version's split files (default: the parent's carried over).
        """
        self._begin()
        self.manifest = commit_parts(self.root, parts, fields or {}, self.parent, self.command, splits=splits,
                                     next_unit=self.unit)
        return self.manifest

    def _clean_up(self) -> None:
        """Delete this write's units, unless a version was committed after all (a failure past the link:
        its files are listed, never deleted)."""
        try:
            newest = (list_versions(self.root) or [None])[-1]
            if newest == (self.parent.version if self.parent is not None else None):
                clear_uncommitted(self.root, self.first_unit)
        except OSError:
            pass     # the error on its way matters more; the next write clears them (step 3)
