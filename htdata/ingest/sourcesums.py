"""Source checksums: what decoders cannot see, a sha256 can.

FFmpeg conceals some H.264 damage without an error (a flipped byte can shift
stored RGB by tens of levels and still decode), so a damaged copy of a
recording can ingest "cleanly". Two defences, both by content hash:

- every episode record keeps `source_sha256`: {file relative to the source
  root: sha256} of each file the episode read, so a later question "was this
  ingested from the bytes we archived?" has an answer;
- a checksum list beside the recordings, in `sha256sum` format (a file named
  `SHA256SUMS` or `*.sha256` anywhere under the source root, paths relative
  to the list's folder), is checked for every file an episode reads: a file
  whose sha256 differs is a warning note by default and, with
  `htdata ingest --verify-sources`, a failure of its episodes (nothing of them
  is ingested); `--verify-sources` also fails files no list covers.

What this cannot detect: damage that happened before the list was made (the
list then describes the damaged bytes), and anything in a file no list
covers unless --verify-sources is given. Only the episodes this run ingests
are hashed (each file once per run): reused episodes cost nothing.
"""

from __future__ import annotations

import dataclasses
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from htdata.errors import DatasetError, EpisodeError
from htdata.ingest.plan import failure_entry
from htdata.store.fsutil import sha256_file

LIST_NAMES = ("SHA256SUMS",)
LIST_SUFFIX = ".sha256"
_LINE = re.compile(r"([0-9a-fA-F]{64}) [ *](.+)")


def read_checksum_lists(root: Path) -> dict[str, tuple[str, str]]:
    """{absolute file path: (sha256, "LIST:line")} from every checksum list under `root`."""
    found: dict[str, tuple[str, str]] = {}
    lists = sorted(p for p in Path(root).rglob("*") if p.is_file()
                   and (p.name in LIST_NAMES or p.name.endswith(LIST_SUFFIX)))
    for lst in lists:
        for n, line in enumerate(lst.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            line = line.rstrip("\n")
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            m = _LINE.fullmatch(line.strip())
            if not m:
                raise DatasetError(f"{lst}:{n}: not a sha256sum line ('<64 hex digits>  <file>'): {line[:80]!r}")
            found[str((lst.parent / m.group(2)).resolve())] = (m.group(1).lower(), f"{lst}:{n}")
    return found


@dataclasses.dataclass
class SourceCheck:
    refs: list                      # refs that may be ingested, extra["source_sha256"] filled
    failures: list[dict]            # report failure entries (stage "verify")
    notes: list[str]


def hash_files(paths: list[str], threads: int) -> dict[str, str]:
    """{path: sha256} of every path, `threads` at a time: hashlib releases the GIL on large updates, so
    threads hash in parallel (the driver does this before any unit runs: serial, it would cap scaling)."""
    unique = list(dict.fromkeys(paths))
    if threads <= 1 or len(unique) <= 1:
        return {p: sha256_file(p) for p in unique}
    with ThreadPoolExecutor(max_workers=min(threads, len(unique))) as pool:
        return dict(zip(unique, pool.map(sha256_file, unique)))


def check_sources(refs: list, roots: dict[str, Path], strict: bool, threads: int = 1) -> SourceCheck:
    """Hash every file of `refs` (once, `threads` files at a time), compare with the checksum lists of their
    source roots.

    `roots`: episode id -> source root. `strict` (--verify-sources): a mismatch or a file no list covers
    fails the episode; otherwise a mismatch is a note and the episode is ingested.
    """

    lists: dict[Path, dict] = {}
    digests = hash_files([str(Path(p).resolve()) for ref in refs for p in ref.source_files], threads)
    noted: set[str] = set()          # a file many episodes share (an OpenTouch scene) is reported once
    out = SourceCheck(refs=[], failures=[], notes=[])
    for ref in refs:
        root = Path(roots[ref.episode_id])
        if root not in lists:
            lists[root] = read_checksum_lists(root)
        listed = lists[root]
        sums, problem = {}, None
        for path in ref.source_files:
            resolved = str(Path(path).resolve())
            sha = digests[resolved]
            try:
                rel = Path(path).relative_to(root).as_posix()
            except ValueError:
                rel = str(path)
            sums[rel] = sha
            expected = listed.get(resolved)
            if expected is not None and expected[0] != sha:
                msg = (f"sha256 {sha[:16]}... differs from {expected[1]} ({expected[0][:16]}...): not the bytes the "
                       f"checksum list describes (a damaged or replaced copy)")
                if strict:
                    problem = problem or EpisodeError(ref, None, msg, file=path)
                elif resolved not in noted:
                    noted.add(resolved)
                    out.notes.append(f"warning: {path}: {msg}; ingested anyway (--verify-sources refuses it)")
            elif expected is None and strict:
                problem = problem or EpisodeError(ref, None, "in no checksum list (SHA256SUMS or *.sha256 in "
                                                  "sha256sum format under the source folder); --verify-sources "
                                                  "needs one", file=path)
        if problem is not None:
            out.failures.append(failure_entry("verify", ref.source, problem, ref.source_ref))
            continue
        out.refs.append(dataclasses.replace(ref, extra={**ref.extra, "source_sha256": dict(sorted(sums.items()))}))
    return out
