"""One writer per dataset: a lock file naming its holder (host, pid, start time, command).

Every command that writes a dataset (ingest, split, rm, trim, merge, gc)
holds `DATASET/.lock` while it works. The file is written complete to a
temp file and linked into place (link fails if the lock exists), so two
writers can never both get it and nobody ever reads a half-written lock. A second writer is
refused with a message naming the holder. A lock whose holder is dead (same
host, pid no longer running, or running but started after the lock was
taken, i.e. the pid was reused) is stale: it is taken over, and the
takeover is reported to the caller (`WriterLock.note`). Locks held from
another host are never broken automatically: only that host can tell
whether its holder lives (remove the file by hand once you know).

Taking the lock first refuses a dataset whose writers' folders (shards/, .work/, ...) are symlinks
(htdata/store/writable.py): nothing is written or deleted through one.

Readers take no lock: a version, once committed, never changes.
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import os
import socket
import sys
import time
from pathlib import Path

from htdata.errors import HtdataError
from htdata.fileio import write_bytes_exclusive
from htdata.store.writable import check_writable_folders

LOCK_FILE = ".lock"
TAKEOVER_STALE_S = 30.0   # a takeover mutex older than this was left by a writer killed inside it


def is_lock_file(name: str) -> bool:
    """The lock, its takeover mutex (`.lock.takeover`) or a temp file a writer is trying the lock with
    (`..lock.PID.tmp`, fileio.write_bytes_exclusive): files of a writer racing for the dataset now, which no
    cleanup may remove and no "is OUT empty" check may count."""
    return name == LOCK_FILE or name.startswith(LOCK_FILE + ".") or name.startswith("." + LOCK_FILE + ".")


class DatasetLocked(HtdataError, RuntimeError):
    """Another live writer holds the dataset (or its lock cannot be taken): an htdata error, one line at the
    command line; still a RuntimeError, as before."""


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _process_start(pid: int) -> float | None:
    """Start time (seconds since boot, Linux) of `pid`, or None if unknown."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # exists, owned by someone else
        return True
    return True


def holder_alive(holder: dict) -> bool | None:
    """True/False for a holder on this host; None when it cannot be known (another host)."""
    if holder.get("host") != socket.gethostname():
        return None
    pid = int(holder.get("pid", -1))
    if pid <= 0 or not pid_alive(pid):
        return False
    started = holder.get("pid_start")
    now_start = _process_start(pid)
    if started is not None and now_start is not None and abs(now_start - float(started)) > 1.0:
        return False          # the pid was reused by a later process
    return True


def describe(holder: dict) -> str:
    return (f"pid {holder.get('pid')} on {holder.get('host')} since {holder.get('started')} "
            f"({holder.get('command') or 'unknown command'})")


class WriterLock:
    """`with WriterLock(root, command): ...`; raises DatasetLocked when a live writer holds it."""

    def __init__(self, root: str | os.PathLike, command: str | None = None):
        self.path = Path(root) / LOCK_FILE
        self.command = command if command is not None else " ".join(sys.argv)
        self.note: str | None = None
        self._held = False

    def _record(self) -> bytes:
        pid = os.getpid()
        return (json.dumps({"host": socket.gethostname(), "pid": pid, "pid_start": _process_start(pid),
                            "started": _now(), "command": self.command}) + "\n").encode()

    def _try_create(self) -> bool:
        """Create the lock with its content complete: written to a temp file, then linked (fails if taken).

        A lock file is therefore never seen half written by another writer.
        """
        try:   # the temp file goes whatever happens (a full disk fails the write: no temp left)
            write_bytes_exclusive(self.path, self._record())
            return True
        except FileExistsError:
            return False
        except OSError as exc:
            if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):   # one line, not a traceback inside another
                raise DatasetLocked(f"{self.path.parent}: cannot take the writer lock {self.path}: "
                                    f"{exc.strerror} (a read-only dataset?); nothing was written") from None
            raise

    def _take_over(self, stale: dict) -> None:
        """Remove the lock if it still holds `stale`, under a short mutex so two writers cannot both
        take it over (one could otherwise remove the other's fresh lock)."""
        mutex = self._mutex()
        try:
            fd = os.open(mutex, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            try:
                if mutex.is_symlink() or not mutex.is_file():
                    raise DatasetLocked(f"{mutex}: a directory (or another non-file) where the writer lock's "
                                        f"takeover mutex goes; no writer can take over the stale lock "
                                        f"{self.path} until it is removed")
                # its writer died inside (or its time is in the future: not one a live writer wrote just now)
                if abs(time.time() - mutex.stat().st_mtime) > TAKEOVER_STALE_S:
                    mutex.unlink(missing_ok=True)
            except FileNotFoundError:
                pass
            time.sleep(0.01)
            return
        try:
            if self.read_holder() == stale:
                self.path.unlink(missing_ok=True)
                self.note = (f"took over a stale lock of a writer that is no longer running: "
                             f"{describe(stale) if stale else 'unreadable lock file'}")
        finally:
            os.close(fd)
            mutex.unlink(missing_ok=True)

    def read_holder(self) -> dict | None:
        try:
            holder = json.loads(self.path.read_bytes().decode("utf-8"))
        except FileNotFoundError:
            return None
        except UnicodeDecodeError:
            raise DatasetLocked(f"{self.path}: not a writer lock htdata wrote (binary content); if no writer is "
                                f"running on this dataset, remove it by hand") from None
        except (OSError, json.JSONDecodeError):
            return {}   # half-written by a writer killed mid-write: no live holder wrote it fully
        return holder if isinstance(holder, dict) else {}

    def acquire(self) -> "WriterLock":
        # every writer takes this lock first: nothing is written or deleted through a symlinked folder
        check_writable_folders(self.path.parent)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.is_dir() or (self.path.exists() and not self.path.is_file()):
            raise DatasetLocked(f"{self.path}: is a directory (or another non-file), not a writer lock; no writer "
                                f"can take the dataset until it is removed (rmdir it if nothing of yours is in it)")
        for _ in range(200):   # bounded: racing writers may release / take over between our steps
            if self._try_create():
                self._held = True
                return self
            holder = self.read_holder()
            if holder is None:
                continue          # released meanwhile: try again
            alive = holder_alive(holder) if holder else False
            if alive is None:
                raise DatasetLocked(f"{self.path.parent}: held by another host's writer, {describe(holder)}; "
                                    f"if that writer is gone, remove {self.path} by hand")
            if alive:
                raise DatasetLocked(f"{self.path.parent}: another writer holds the dataset: {describe(holder)}")
            self._take_over(holder)
        mutex = self._mutex()
        if mutex.exists():
            raise DatasetLocked(f"{mutex}: a takeover of the stale writer lock {self.path} is under way or was left "
                                f"by a writer killed inside it (removed by the next writer once "
                                f"{TAKEOVER_STALE_S:.0f} s old); if no writer is running, remove it by hand")
        raise DatasetLocked(f"{self.path.parent}: could not take the writer lock (contended); try again")

    def _mutex(self) -> Path:
        return self.path.with_name(f"{LOCK_FILE}.takeover")

    def release(self) -> None:
        if not self._held:
            return
        holder = self.read_holder()
        if holder and holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
            self.path.unlink(missing_ok=True)
        self._held = False

    def __enter__(self) -> "WriterLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
