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

Where the hashing happens: in the work units, on the node that reads the
bytes (htdata/ingest/unit.py `hash_sources`), never in the driver. The plan
gives each source file of the run to ONE unit, the first that reads it
(htdata/ingest/plan.py `assign_hashing`): a scene file several episodes share
is hashed once per run. The driver reads only the checksum lists: before the
units run, `plan_verification` fails (with --verify-sources) the episodes
with a file no list covers; after, `check_digests` compares the digests the
records carry with the lists, fails every unit whose episodes read a
mismatching (strict) or unreadable file (its records dropped, its shards
deleted: nothing of it is committed) and writes `source_sha256` into the
episode records the commit writes. Every path is resolved once per run
(`RealPaths`, shared with the plan): no per-file syscalls twice.

What this cannot detect: damage that happened before the list was made (the
list then describes the damaged bytes), and anything in a file no list
covers unless --verify-sources is given. Only the episodes this run ingests
are hashed: reused episodes cost nothing.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

from htdata.errors import DatasetError, EpisodeError
from htdata.ingest.plan import failure_entry
from htdata.ingest.workdir import clear_unit_files
from htdata.source.adapters.sourcetree import RealPaths, plain_path

LIST_NAMES = ("SHA256SUMS",)
LIST_SUFFIX = ".sha256"
_LINE = re.compile(r"([0-9a-fA-F]{64}) [ *](.+)")


def read_checksum_lists(root: Path) -> dict[str, tuple[str, str]]:
    """{absolute file path: (sha256, "LIST:line")} from every checksum list under `root`."""
    found: dict[str, tuple[str, str]] = {}
    # the name first: a stat only for a list's name, not for every file of the tree (a JPEG folder: one a frame)
    lists = sorted(p for p in Path(root).rglob("*") if (p.name in LIST_NAMES or p.name.endswith(LIST_SUFFIX))
                   and p.is_file())
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


class ChecksumLists:
    """The checksum lists of each source root, read once per run (small files: the driver's only reads)."""

    def __init__(self):
        self._by_root: dict[Path, dict] = {}

    def of(self, root: Path | str) -> dict[str, tuple[str, str]]:
        root = Path(root)
        if root not in self._by_root:
            self._by_root[root] = read_checksum_lists(root)
        return self._by_root[root]


@dataclasses.dataclass
class SourceCheck:
    refs: list                      # refs that may be ingested
    failures: list[dict]            # report failure entries (stage "verify")
    notes: list[str]


def plan_verification(refs: list, roots: dict[str, Path], strict: bool, lists: ChecksumLists,
                      real: RealPaths | None = None) -> SourceCheck:
    """With `strict` (--verify-sources), fail before any unit runs the episodes reading a file no checksum
    list covers (no digest can save them); every other ref goes on. `roots`: episode id -> source root."""
    out = SourceCheck(refs=[], failures=[], notes=[])
    real = real or RealPaths()
    for ref in refs:
        listed = lists.of(roots[ref.episode_id]) if strict else {}
        unlisted = next((p for p in ref.source_files if strict and real(p) not in listed), None)
        if unlisted is None:
            out.refs.append(ref)
            continue
        problem = EpisodeError(ref, None, "in no checksum list (SHA256SUMS or *.sha256 in sha256sum format under "
                               "the source folder); --verify-sources needs one", file=unlisted)
        out.failures.append(failure_entry("verify", ref.source, problem, ref.source_ref))
    return out


class _Names:
    """(resolved path, path relative to the source root) of source files, each named once per run."""

    def __init__(self, real: RealPaths):
        self._names: dict[tuple, tuple[str, str]] = {}
        self._real = real

    def __call__(self, path: str, root: Path) -> tuple[str, str]:
        key = (path, root)
        if key not in self._names:
            prefix = str(root) + "/"
            if plain_path(path) and path.startswith(prefix) and prefix != "//":   # pathlib's answer, no Path made
                rel = path[len(prefix):]
            else:
                try:
                    rel = Path(path).relative_to(root).as_posix()
                except ValueError:
                    rel = str(path)
            self._names[key] = (self._real(path), rel)
        return self._names[key]


def _episode_sums(ref, root: Path, digests: dict, unreadable: dict, listed: dict, strict: bool,
                  warned: dict[str, str], names: _Names) -> tuple[dict, EpisodeError | None]:
    """({relative path: sha256}, the first problem) of one episode's files; lenient mismatches go to `warned`."""
    sums, problem = {}, None
    for path in ref.source_files:
        resolved, rel = names(path, root)
        sha = digests.get(resolved)
        if sha is None:
            why = unreadable.get(resolved, "no work unit hashed it")
            problem = problem or EpisodeError(ref, None, f"sha256 not available: the file could not be read "
                                              f"({why})", file=path)
            continue
        sums[rel] = sha
        expected = listed.get(resolved)
        if expected is not None and expected[0] != sha:
            msg = (f"sha256 {sha[:16]}... differs from {expected[1]} ({expected[0][:16]}...): not the bytes the "
                   f"checksum list describes (a damaged or replaced copy)")
            if strict:
                problem = problem or EpisodeError(ref, None, msg, file=path)
            else:
                warned.setdefault(resolved, f"warning: {path}: {msg}; ingested anyway (--verify-sources refuses it)")
    return dict(sorted(sums.items())), problem


def check_digests(tasks: list, records: list[dict], strict: bool, lists: ChecksumLists,
                  real: RealPaths | None = None) -> list[str]:
    """Check the digests the units' records carry (every record of the run, resumed ones too) against the
    checksum lists; returns the warning notes (one per mismatching file, lenient mode).

    In place: each ingested episode record gets `source_sha256`; a unit with an episode whose file could
    not be hashed, or (with `strict`) differs from its list, loses its episodes, samples and shards (a
    "verify" failure per episode; its shard files and record deleted, so a re-run runs it again).
    Per unit and file, no Python per frame.
    """
    digests: dict[str, str] = {}
    unreadable: dict[str, str] = {}
    for rec in records:
        digests.update(rec["source_sha256"])
        unreadable.update({p: f"{why}; hashed by unit {rec['unit']}" for p, why in rec["source_unreadable"].items()})
    warned: dict[str, str] = {}
    names = _Names(real or RealPaths())
    by_unit = {t.unit: t for t in tasks}
    for rec in records:
        task = by_unit[rec["unit"]]
        refs = {r.episode_id: r for r in task.episodes}
        listed = lists.of(task.root)
        problems = []
        for ep in rec["episodes"]:
            sums, problem = _episode_sums(refs[ep["episode_id"]], Path(task.root), digests, unreadable, listed,
                                          strict, warned, names)
            ep["source_sha256"] = sums
            if problem is not None:
                problems.append(problem)
        if problems:
            _fail_unit(rec, task, refs, problems)
    return list(warned.values())


def _fail_unit(rec: dict, task, refs: dict, problems: list[EpisodeError]) -> None:
    """Nothing of the unit is committed: its episodes become "verify" failures, its files are deleted."""
    first = {p.episode_id: p for p in reversed(problems)}
    for ep in rec["episodes"]:
        ref = refs[ep["episode_id"]]
        problem = first.get(ep["episode_id"]) or EpisodeError(ref, None, f"its work unit failed verification: "
                                                              f"{problems[0].message}", file=problems[0].file)
        rec["failures"].append(failure_entry("verify", ref.source, problem, ref.source_ref))
    rec.update(episodes=[], shards=[], rows="", frames=0, dropped=[], layouts={}, calibrations={})
    clear_unit_files(Path(task.out), task.unit)
