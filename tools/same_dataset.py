"""Do two revisions write the same dataset for the same inputs? Byte for byte.

    .venv/bin/python tools/same_dataset.py BASE_REV [NEW_REV] [--scale tiny|small]

Exports both revisions (git archive; NEW_REV defaults to the working tree),
writes the sample corpus once with BASE, ingests it with each revision
(inline, so scheduling cannot reorder anything) and compares every shard,
the index and the episode records byte for byte (as a reader gets them, through this tree's
loaders, written out as format 3 stored them: episodes.jsonl lines with sorted keys, index.npy as
np.save writes it; so datasets of different format versions compare too). dataset.json is
compared with its run-dependent fields removed (and where it keeps its records: format 3's file
names, format 4's segments), its shard list as a reader sees it. Exit 0 when everything is
identical, 1 otherwise.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_compare import REPO, corpus_formats, export, run_py  # noqa: E402  (a sibling tool)

sys.path.insert(0, str(REPO))
from htdata.store.manifest import load_index, load_records  # noqa: E402  (this tree reads every format)

RUN_FIELDS = ("created", "sources", "change", "htdata_version", "episodes_file", "index_file", "version",
              "parent", "next_unit", "splits", "format_version", "segments")


def ingest(tree: Path, raw: Path, out: Path) -> None:
    args = ["-m", "htdata.cli", "ingest", "--workers", "0", "--quiet"]
    for name in corpus_formats(raw):
        args += ["--pipeline", f"pipelines/{name}.toml={raw / name}"]
    run_py(tree, args + [str(out)], cwd=tree)


def files(out: Path) -> dict[str, bytes]:
    manifest, episodes = load_records(out)
    got = {f"shards/{p.name}": p.read_bytes() for p in sorted((out / "shards").glob("*.tar"))}
    got["episodes"] = "".join(json.dumps(ep, sort_keys=True) + "\n" for ep in episodes).encode()
    buf = io.BytesIO()
    np.save(buf, np.asarray(load_index(out, manifest=json.loads((out / "dataset.json").read_text()))),
            allow_pickle=False)
    got["index"] = buf.getvalue()
    got["manifest (run fields removed)"] = json.dumps(
        {k: v for k, v in manifest.items() if k not in RUN_FIELDS}, sort_keys=True).encode()
    return got


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("base")
    p.add_argument("new", nargs="?", default=None)
    p.add_argument("--scale", default="small", choices=("tiny", "small"))
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="htdata-same-") as tmp:
        tmp = Path(tmp)
        base, new = export(args.base, tmp / "base"), export(args.new, tmp / "new")
        raw = tmp / "raw"
        run_py(base, ["-m", "htdata.cli", "sample", str(raw), "--seed", "0", "--scale", args.scale], cwd=base)
        ingest(base, raw, tmp / "ds_base")
        ingest(new, raw, tmp / "ds_new")
        a, b = files(tmp / "ds_base"), files(tmp / "ds_new")
    differ = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    shards = sum(1 for k in a if k.startswith("shards/"))
    print(f"base {args.base} vs new {args.new or 'working tree'}: {shards} shards, index, episode records, manifest")
    if differ:
        print(f"DIFFERENT: {len(differ)} file(s): {', '.join(differ[:10])}")
        return 1
    print(f"identical: {len(a)} files byte for byte ({sum(len(v) for v in a.values())} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
