"""The dataset at HT-Bench's size (issue 47): every command's wall time, peak memory and bytes written per commit.

HT-Bench holds ~7.8M tactile frames in ~20k episodes. Ingesting that much here would take hours, so
the dataset is built by replication: the sample raw-count glove's five recordings (306 frames each,
glove only, maps stored) are ingested once, then copied as new work units until the index holds the
wanted number of samples. A copy's shards are hard links to the base unit's shards (no bytes, the
same sha256) under the copy's own unit number, and its episodes are the base's records under new ids;
the version is committed by the real writer (`NewVersion.commit`), so the manifest, episodes.jsonl,
index.npy and their checksums are exactly what an ingest of that many recordings would write.

What is real and what is shared: the metadata (manifest, shard list, episode records, index rows) is
real at full size; the shard BYTES are shared, and the reader checks every member's key against its
record, so only the base's own episodes can be decoded. Left out: the commands that decode every
sample or every episode (`stats`, `card`, `validate`: it decodes each episode's first frame and hashes
every shard; `publish` uploads every shard; `merge` hashes every shard it links): their cost is
O(samples) or O(shard bytes) by design, measured per sample in the other sections. The commands
measured read metadata, or decode one base episode (`trim`, `view`).

Each command runs as its own process (`htdata ...`, by this interpreter), timed from outside: wall seconds, the
process's own peak resident memory (its VmHWM, written at exit; its worker processes are not counted), and
the bytes of the files it created or changed in the dataset (a hard link to an existing file counts 0: it
writes no data).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from htdata.benchmarks.maps import _layouts_on_path
from htdata.format.table import INDEX_DTYPE, SHARDS_DIR
from htdata.ingest.pipeline import load_pipeline
from htdata.ingest.plan import Source
from htdata.ingest.run import ingest
from htdata.store.parts import Part
from htdata.store.storage import CACHE_ENV
from htdata.synthetic.rawglove import write_rawglove
from htdata.write.newversion import NewVersion

HT_BENCH_SAMPLES = 7_800_000


def base_dataset(work: Path) -> Path:
    """The sample raw-count glove's recordings ingested with the default pipeline (maps stored)."""
    src, out = work / "rawglove_src", work / "base"
    if not (src / "truth.json").exists():
        write_rawglove(src)
    if not (out / "dataset.json").exists():
        shutil.rmtree(out, ignore_errors=True)
        with _layouts_on_path(src / "layouts"):
            ingest([Source(load_pipeline("native"), src.resolve())], out, workers=0, progress=False,
                   layout_dirs=(str(src / "layouts"),), command="htdata bench (HT-Bench size: base)")
    return out


def replicate(base: Path, root: Path, samples: int) -> dict:
    """`root` = `base` plus copies of its units until the index holds >= `samples` rows (one new version)."""
    shutil.rmtree(root, ignore_errors=True)
    shutil.copytree(base, root, copy_function=os.link)      # the base's own files: links, its versions kept
    t0 = time.perf_counter()
    with NewVersion(root, "htdata bench (HT-Bench size: replicate)") as nv:
        base_parts = nv.parent.parts()
        parts, rows, k = list(base_parts), sum(len(p.rows) for p in base_parts), 0
        while rows < samples:
            part = base_parts[k % len(base_parts)]
            unit = nv.take_unit()
            shards = []
            for j, s in enumerate(part.shards):
                name = f"shard-{unit:06d}-{j:03d}.tar"
                os.link(root / SHARDS_DIR / s["name"], root / SHARDS_DIR / name)
                shards.append({**s, "name": name})
            episodes = [{**e, "episode_id": f"{e['episode_id']}-u{unit:06d}"} for e in part.episodes]
            parts.append(Part(unit=unit, shards=shards, rows=part.rows.copy(), episodes=episodes,
                              records_checked=True))
            rows += len(part.rows)
            k += 1
        manifest = nv.commit(parts)
    return {"samples": rows, "episodes": sum(len(p.episodes) for p in parts), "units": len(parts),
            "version": int(manifest["version"]), "build_s": time.perf_counter() - t0,
            # commands that read samples must pick a base episode: a copy's records name keys its shared
            # shard does not hold (the reader checks every member's key: "index and shard disagree")
            "first_episode": parts[0].episodes[0]["episode_id"],
            "base_last_episode": base_parts[-1].episodes[-1]["episode_id"],
            "task": parts[0].episodes[0]["task"]}


def _files(root: Path) -> dict[str, tuple[int, int, int]]:
    """{relative path: (inode, size, mtime_ns)} of every file under `root`."""
    out = {}
    for dirpath, _, names in os.walk(root):
        for n in names:
            p = Path(dirpath) / n
            st = p.stat()
            out[str(p.relative_to(root))] = (st.st_ino, st.st_size, st.st_mtime_ns)
    return out


def bytes_written(before: dict, after: dict) -> int:
    """Bytes of files created or rewritten between two `_files` listings; a new name for an inode that was
    already there (a hard link) writes no data."""
    inodes = {v[0] for v in before.values()}
    total = 0
    for path, (ino, size, mtime) in after.items():
        old = before.get(path)
        if old == (ino, size, mtime) or (old is None and ino in inodes):
            continue
        total += size
    return total


def run_command(args: list[str], root: Path, label: str, cache: Path) -> dict:
    """Run `htdata ARGS` in this interpreter (or `python -c CODE ...` for args[0] == "-c"); wall seconds, its
    peak resident memory (the process's own VmHWM, written at exit: a child's ru_maxrss on Linux starts at
    its parent's, here hundreds of MB), the bytes it wrote into the dataset and into the local cache
    `cache` (HTDATA_CACHE: where a reader assembles a large format 4 index once, htdata/store/segments.py)."""
    before, cached = _files(root), _files(cache) if cache.is_dir() else {}
    peak_file = root.parent / f"{root.name}.peak"
    peak_file.unlink(missing_ok=True)
    cmd = [sys.executable, "-c", PEAK_CODE + (args[1] if args[0] == "-c" else CLI_CODE),
           *(args[2:] if args[0] == "-c" else args)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          env={**os.environ, PEAK_ENV: str(peak_file), CACHE_ENV: str(cache)})
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        tail = done.stdout.decode(errors="replace")[-1500:]
        raise RuntimeError(f"{label}: `{' '.join(cmd)}` exited {done.returncode}:\n{tail}")
    return {"command": label, "wall_s": wall, "peak_mib": int(peak_file.read_text()) / 1024,
            "bytes_written": bytes_written(before, _files(root)),
            "cache_bytes_written": bytes_written(cached, _files(cache) if cache.is_dir() else {})}


PEAK_ENV = "HTDATA_BENCH_PEAK_FILE"
PEAK_CODE = ("import atexit as _a, os as _o\n"
             "def _peak():\n"
             "    kb = next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1]\n"
             f"    open(_o.environ['{PEAK_ENV}'], 'w').write(kb)\n"
             "_a.register(_peak)\n")
CLI_CODE = "import sys; from htdata.cli import main; sys.exit(main())"     # `htdata ARGS`, this interpreter
OPEN_CODE = ("import sys; from htdata.read.reader import DatasetReader\n"
             "with DatasetReader(sys.argv[1]) as r:\n"
             "    print(len(r.index), len(r.episodes), r.episodes[len(r.episodes) // 2]['episode_id'])")


def commands(root: Path, work: Path, shape: dict) -> list[tuple[str, list[str]]]:
    """The commands measured, in the order they run (each write makes the next version)."""
    v = shape["version"]     # the replicated version; split, rm and trim make v+1, v+2, v+3
    return [
        ("open (reader: manifest, episode records, index)", ["-c", OPEN_CODE, str(root)]),
        ("open again (a large index: from the cache)", ["-c", OPEN_CODE, str(root)]),
        ("log", ["log", str(root)]),
        (f"split --ood-task {shape['task']}", ["split", str(root), "--ood-task", shape["task"], "--name", "main"]),
        ("rm one episode", ["rm", str(root), shape["first_episode"]]),
        ("trim one episode (--frames 10:)", ["trim", str(root), shape["base_last_episode"], "--frames", "10:"]),
        ("diff (rm's version against split's)", ["diff", str(root), str(v + 1), str(v + 2)]),
        ("view one episode (--save)", ["view", str(root), "--save", str(work / "view.rrd")]),
        ("gc --dry-run", ["gc", str(root), "--dry-run"]),
        ("gc --keep-versions 2 --retention 0 --force", ["gc", str(root), "--keep-versions", "2",
                                                        "--retention", "0", "--force"]),
    ]


def size_rows(work: Path, sizes: tuple[int, ...]) -> dict:
    """Per size: the replicated dataset's shape and every command's figures."""
    work.mkdir(parents=True, exist_ok=True)
    base = base_dataset(work)
    out = {"base": "sample raw-count glove, 5 recordings x 306 frames, glove only, maps stored",
           "ht_bench_samples": HT_BENCH_SAMPLES, "sizes": []}
    for n in sizes:
        root = work / f"ds_{n}"
        shape = replicate(base, root, n)
        stored = json.loads((root / "dataset.json").read_text())
        shape["format_version"] = stored["format_version"]
        shape["index_bytes"] = INDEX_DTYPE.itemsize * int(stored["counts"]["samples"])
        shape["manifest_bytes"] = len((root / "dataset.json").read_bytes())
        cache = work / f"cache_{n}"
        shutil.rmtree(cache, ignore_errors=True)
        rows = [run_command(args, root, label, cache) for label, args in commands(root, work, shape)]
        shutil.rmtree(cache, ignore_errors=True)
        out["sizes"].append({**shape, "commands": rows})
        shutil.rmtree(root, ignore_errors=True)
    return out


def size_markdown(d: dict) -> list[str]:
    lines = [f"Built by replication (htdata/benchmarks/htbenchsize.py): {d['base']}, copied as new work units "
             f"(shards hard-linked, metadata real) up to each size; HT-Bench holds ~{d['ht_bench_samples']:,} "
             f"samples. Each command is its own process, in this order (each write makes the next version); "
             f"bytes written = files it created or rewrote in the dataset; cache = what it wrote to the local "
             f"cache (HTDATA_CACHE: a large format 4 index, assembled once per version).", ""]
    for s in d["sizes"]:
        lines += [f"{s['samples']:,} samples, {s['episodes']:,} episodes, {s['units']:,} units, format "
                  f"{s.get('format_version', 3)}; index {s['index_bytes'] / 1e6:.0f} MB; manifest "
                  f"{s.get('manifest_bytes', 0) / 1e3:.0f} kB; built in {s['build_s']:.0f} s:", "",
                  "| command | wall s | peak MiB | bytes written | cache bytes written |", "|---|---|---|---|---|"]
        lines += [f"| {c['command']} | {c['wall_s']:.2f} | {c['peak_mib']:.0f} | {c['bytes_written']:,} | "
                  f"{c.get('cache_bytes_written', 0):,} |" for c in s["commands"]]
        lines.append("")
    return lines
