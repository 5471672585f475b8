"""A dataset as format 3 stored it (readers of old datasets, `htdata upgrade`); records re-sealed by a forger.

`as_format3(root)` rewrites every version of a committed dataset the way htdata 3 wrote it: each
version its own versions/vN/episodes.jsonl and index.npy, the shard list in its manifest, no
segments/. The records are those the format 4 reader gives, so a format 3 reader of the result
must see the same dataset (tests/store/test_segments.py compares them). `reseal_records` and
`reseal_index` edit a version's records where they are stored, in either format, and re-seal every
sha256 over them: what only the checks of the content can catch.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path

import numpy as np

from htdata.format.table import EPISODES_FILE, INDEX_FILE, MANIFEST_FILE, SEGMENTS_DIR
from htdata.store.manifest import load_index, load_manifest, load_records
from htdata.store.segments import load_segment_index
from htdata.store.versions import list_versions, version_dir, version_manifest_file


def as_format3(root: Path) -> Path:
    """Rewrite the format 4 dataset at `root` as format 3, every version; returns `root`."""
    root = Path(root)
    for n in list_versions(root):
        stored = load_manifest(root, version=n, validate=False)
        manifest, episodes = load_records(root, stored)
        rows = load_segment_index(root, stored)
        episodes_bytes = "".join(json.dumps(ep, sort_keys=True) + "\n" for ep in episodes).encode()
        buf = io.BytesIO()
        np.save(buf, np.asarray(rows), allow_pickle=False)
        folder = root / version_dir(n)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / EPISODES_FILE).write_bytes(episodes_bytes)
        (folder / INDEX_FILE).write_bytes(buf.getvalue())
        manifest = {k: v for k, v in manifest.items() if k != "segments"}
        manifest.update({"format_version": 3, "episodes_file": f"{version_dir(n)}/{EPISODES_FILE}",
                         "index_file": f"{version_dir(n)}/{INDEX_FILE}",
                         "episodes_sha256": hashlib.sha256(episodes_bytes).hexdigest(),
                         "index_sha256": hashlib.sha256(buf.getvalue()).hexdigest()})
        data = (json.dumps(manifest, indent=2) + "\n").encode()
        (root / version_manifest_file(n)).write_bytes(data)
        if n == list_versions(root)[-1]:
            (root / MANIFEST_FILE).write_bytes(data)
    shutil.rmtree(root / SEGMENTS_DIR, ignore_errors=True)
    return root


def reseal_records(root: Path, edit) -> None:
    """Apply `edit(records)` (in place) to the current version's episode records where they are stored, and
    re-seal every sha256 that covers them, as a careful forger would: format 4, the records in its segments
    (each segment's records_sha256, the manifest's episodes_sha256); format 3, its episodes.jsonl. Both
    manifest copies are rewritten, so that only checks of the records' content can notice."""
    from tests.factories import rewrite_manifest

    root = Path(root)
    manifest = load_manifest(root, validate=False)
    if "segments" not in manifest:
        path = root / manifest["episodes_file"]
        records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        edit(records)
        path.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
        manifest["episodes_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
        rewrite_manifest(root, manifest)
        return
    docs = [json.loads((root / e["records"]).read_bytes()) for e in manifest["segments"]]
    edit([r for doc in docs for unit in doc["units"] for r in unit["episodes"]])
    for entry, doc in zip(manifest["segments"], docs):
        data = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()
        (root / entry["records"]).write_bytes(data)
        entry["records_sha256"] = hashlib.sha256(data).hexdigest()
    _, episodes = load_records(root, manifest)
    manifest["episodes_sha256"] = hashlib.sha256(
        "".join(json.dumps(ep, sort_keys=True) + "\n" for ep in episodes).encode()).hexdigest()
    rewrite_manifest(root, manifest)


def reseal_index(root: Path, edit) -> None:
    """Apply `edit(rows)` (in place, the global index rows) to the current version's index where it is stored,
    and re-seal every sha256 over it, as a careful forger would: format 4, each segment's rows (shard and
    episode columns back to each unit's, uint32 arithmetic as the reader's) and index_sha256s; format 3, its
    index.npy. Both manifest copies are rewritten, so that only checks of the rows' content can notice."""
    from tests.factories import rewrite_manifest

    root = Path(root)
    manifest = load_manifest(root, validate=False)
    rows = np.array(load_index(root, mmap=False, manifest=manifest))
    edit(rows)
    buf = io.BytesIO()
    np.save(buf, rows, allow_pickle=False)
    manifest["index_sha256"] = hashlib.sha256(buf.getvalue()).hexdigest()
    if "segments" not in manifest:
        (root / manifest["index_file"]).write_bytes(buf.getvalue())
        rewrite_manifest(root, manifest)
        return
    start = shard_base = episode_base = 0
    for entry in manifest["segments"]:
        units = json.loads((root / entry["records"]).read_bytes())["units"]
        samples = [sum(s["samples"] for s in u["shards"]) for u in units]
        shards = np.cumsum([shard_base] + [len(u["shards"]) for u in units])
        episodes = np.cumsum([episode_base] + [len(u["episodes"]) for u in units])
        local = rows[start:start + entry["samples"]].copy()
        local["shard"] -= np.repeat(shards[:-1], samples).astype(np.uint32)
        local["episode"] -= np.repeat(episodes[:-1], samples).astype(np.uint32)
        part = io.BytesIO()
        np.save(part, local, allow_pickle=False)
        (root / entry["index"]).write_bytes(part.getvalue())
        entry["index_sha256"] = hashlib.sha256(part.getvalue()).hexdigest()
        start, shard_base, episode_base = start + entry["samples"], int(shards[-1]), int(episodes[-1])
    rewrite_manifest(root, manifest)
