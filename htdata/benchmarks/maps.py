"""Maps stored or rendered from raw rows ([tactile] maps): what storing them costs in bytes, buys in read speed.

Per adapter of the sample corpus, the same episodes ingested with `maps = "stored"` and `maps = "raw"`
(1 worker). Bytes: every member of every shard, by kind (rgb jpg, tactile maps, raw rows, bend, json, the
tar headers and padding = shard bytes minus member bytes) per frame, for both, and the total per frame and
at 10M frames. Read speed, side by side, alternating A/B runs (medians): TactileFrameDataset items/s
(maps_from="stored" on the stored dataset: the EXR decoded; the default on the other: rendered) and
DatasetReader.decoded samples/s. Exactness: every rendered map against the float32 map the ingest computes before the codec
(`ingest_map_difference`), and the stored maps against the rendered ones (the codec's rounding).
Ingest: frames/s and encode-stage seconds of the two ingests (one run each, so indicative only).

The default is stored maps (`RULE`: the format's promise to readers without htdata); `pick_default` says
what the "raw" opt-in measured against it, and the report whether the pipeline's default ("auto",
resolved for a new dataset: htdata/format/mapstorage.py) is the rule's pick.

Imports inside functions: torch (optional) is loaded by `htdata.read.torchdata` only when measured.
"""

from __future__ import annotations

import os
import resource
import statistics
import tarfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from htdata.benchmarks.ingest import ingest_run
from htdata.benchmarks.mapcost import encode_costs, glove_cost_markdown, projections, stored_maps
from htdata.benchmarks.realclips import load_real_glove
from htdata.benchmarks.realglove import write_native_clips
from htdata.benchmarks.sources import discover
from htdata.benchmarks.tables import fmt, table
from htdata.format.table import HANDS, JSON_MEMBER, SHARDS_DIR, tactile_member
from htdata.format.tactilesettings import TactileConfig
from htdata.glove.layouts import LAYOUTS_ENV
from htdata.ingest.episode import EpisodeStream
from htdata.read.itemoptions import ItemOptions
from htdata.read.reader import DatasetReader
from htdata.synthetic.rawglove import write_rawglove

KINDS = (("rgb", "rgb jpg"), ("maps", "tactile maps"), ("raw", "raw rows"), ("bend", "bend"), ("json", "json"),
         ("tar", "tar headers + padding"))
MAP_MEMBERS = tuple(tactile_member(h) for h in HANDS)
FRAMES_AT_SCALE = 10_000_000
MIN_SAVING = 0.10          # the raw opt-in is worth its trouble when it saves at least this share per frame
RULE = ("a new dataset stores its maps (the published format: 224x224 maps a reader without htdata opens with tar "
        "+ OpenEXR); \"raw\" (maps rendered by htdata's readers) is an explicit opt-in, sound only where "
        "rendering is exact (max |rendered - ingest's map| 0 on every map checked); the tables say what it saves")


def member_kind(name: str) -> str:
    suffix = name.split(".", 1)[1] if "." in name else name
    if suffix == "rgb.jpg":
        return "rgb"
    for stem, kind in (("tactile_", "maps"), ("raw_", "raw"), ("bend_", "bend")):
        if suffix.startswith(stem):
            return kind
    if suffix == "json":
        return "json"
    raise ValueError(f"{name}: member of no known kind")


def bytes_per_frame(root: Path) -> dict:
    """{kind: bytes per frame} over every shard of the dataset's current version, + "total"."""
    reader = DatasetReader(root)
    sums = dict.fromkeys((k for k, _ in KINDS), 0)
    shard_bytes = 0
    for entry in reader.manifest["shards"]:
        path = root / SHARDS_DIR / entry["name"]
        shard_bytes += path.stat().st_size
        with tarfile.open(path) as tar:
            for m in tar.getmembers():
                sums[member_kind(m.name)] += m.size
    sums["tar"] = shard_bytes - sum(sums.values())
    n = max(len(reader), 1)
    out = {k: v / n for k, v in sums.items()}
    out["total"] = shard_bytes / n
    return out


def ingest_map_difference(name: str, root: Path, rendered: Path) -> tuple[float, int]:
    """(max |difference|, maps compared) between the maps rendered from raw rows and the float32 maps the
    ingest computes before any codec (EpisodeStream on the sources): whether rendering is exact.

    Frames are matched by (episode, source frame): a stream without RGB skips RGB-only samples."""
    cfg, adapter, refs = discover(name, root)
    reader = DatasetReader(rendered)
    at = {}
    for i, members in reader.iter_samples(decode=True, suffixes=(JSON_MEMBER,)):
        meta = members["meta"]
        if any(meta["hands"].values()):
            at[(meta["episode_id"], int(meta["source_frame"]))] = i
    diff, n = 0.0, 0
    for ref in refs:
        for frame in EpisodeStream(ref, cfg, adapter, with_rgb=False):
            served = reader.decoded(at[(ref.episode_id, frame.source_frame)], MAP_MEMBERS)["tactile"]
            for hand, m in frame.maps.items():
                diff = max(diff, float(np.abs(served[hand] - m).max()))
                n += 1
    return diff, n


def max_map_difference(stored: Path, rendered: Path) -> tuple[float, int]:
    """(max |difference|, maps compared) between the two datasets' decoded maps, every sample and hand."""
    a, b = DatasetReader(stored), DatasetReader(rendered)
    diff, n = 0.0, 0
    for i in range(len(a)):
        ma, mb = a.decoded(i)["tactile"], b.decoded(i)["tactile"]
        if sorted(ma) != sorted(mb):
            return float("inf"), n
        for hand in ma:
            diff = max(diff, float(np.abs(ma[hand] - mb[hand]).max()))
            n += 1
    return diff, n


def _rate(run) -> float:
    """Things per second of `run()`, which returns how many it did."""
    t0 = time.perf_counter()
    done = run()
    return done / (time.perf_counter() - t0) if done else 0.0


def read_speeds(stored: Path, rendered: Path, limit: int, reps: int) -> dict:
    """Items/s and samples/s, stored maps decoded vs rendered from raw, alternating runs, medians."""
    from htdata.read.torchdata import TactileFrameDataset

    datasets = {"stored": TactileFrameDataset(stored, options=ItemOptions(maps_from="stored")),
                "rendered": TactileFrameDataset(rendered)}
    readers = {"stored": DatasetReader(stored), "rendered": DatasetReader(rendered)}
    items = min(limit, len(datasets["stored"]))
    samples = min(limit, len(readers["stored"]))
    runs: dict[str, list] = {f"{k}_{w}": [] for k in ("frame", "decoded") for w in ("stored", "rendered")}
    for which in ("stored", "rendered"):   # warm-up, not timed: layouts, normalisers, index maps, page cache
        datasets[which][0], readers[which].decoded(0)
    for _ in range(reps):
        for which in ("stored", "rendered"):     # A then B, every repetition
            ds, reader = datasets[which], readers[which]
            runs[f"frame_{which}"].append(_rate(lambda: sum(1 for i in range(items) if ds[i] is not None)))
            runs[f"decoded_{which}"].append(_rate(lambda: sum(1 for i in range(samples) if reader.decoded(i) is not None)))
    med = {k: statistics.median(v) for k, v in runs.items()}
    return {"items": items, "samples": samples, "reps": reps,
            "frame_items_per_s_stored": med["frame_stored"], "frame_items_per_s_rendered": med["frame_rendered"],
            "frame_ratio": med["frame_rendered"] / med["frame_stored"],
            "decoded_samples_per_s_stored": med["decoded_stored"],
            "decoded_samples_per_s_rendered": med["decoded_rendered"],
            "decoded_ratio": med["decoded_rendered"] / med["decoded_stored"]}


def adapter_row(name: str, root: Path, work: Path, limit: int, reps: int) -> dict:
    paths, runs = {}, {}
    for choice in ("stored", "raw"):
        paths[choice] = work / f"maps_{name}_{choice}"
        runs[choice] = ingest_run([(name, root)], paths[choice], 1, (f"tactile.maps={choice}",))
    sizes = {c: bytes_per_frame(p) for c, p in paths.items()}
    diff, compared = max_map_difference(paths["stored"], paths["raw"])
    exact, checked = ingest_map_difference(name, root, paths["raw"])
    stored = DatasetReader(paths["stored"]).manifest["codec"]["tactile"]
    row = {"adapter": name, "samples": len(DatasetReader(paths["stored"])), "maps_compared": compared,
           "stored_pixel_type": stored.get("pixel_type", "half"), "stored_over_rendered_difference": diff,
           "maps_checked_against_ingest": checked, "max_abs_difference": exact,
           "bytes_stored": sizes["stored"], "bytes_raw": sizes["raw"],
           "saving": 1 - sizes["raw"]["total"] / sizes["stored"]["total"],
           "gb_at_10m_stored": sizes["stored"]["total"] * FRAMES_AT_SCALE / 1e9,
           "gb_at_10m_raw": sizes["raw"]["total"] * FRAMES_AT_SCALE / 1e9,
           # what it does to the ingest (one run each, not the ingest section's alternating medians)
           **{f"ingest_{k}_{c}": v for c, r in runs.items()
              for k, v in (("frames_per_s", r["frames_per_s"]), ("encode_s", r.get("stages_s", {}).get("encode", 0.0)))}}
    row.update(read_speeds(paths["stored"], paths["raw"], limit, reps))
    return row


def pick_default(rows: list[dict]) -> tuple[str, str]:
    """(default, why) by RULE: "stored"; `why` says what the "raw" opt-in measured against it."""
    exact = all(r["max_abs_difference"] == 0 for r in rows)
    why = (f"the raw opt-in is exact: {'yes' if exact else 'NO (do not offer it)'}; reads at "
           f"{min(min(r['frame_ratio'], r['decoded_ratio']) for r in rows):.2f}x or more of stored; saves "
           f"{min(r['saving'] for r in rows):.0%} or more of the bytes per frame (least >= {MIN_SAVING:.0%}: "
           f"{'yes' if all(r['saving'] >= MIN_SAVING for r in rows) else 'no'})")
    return "stored", why


@contextmanager
def _layouts_on_path(folder: Path):
    """$HTDATA_LAYOUTS = `folder` for the block (the raw-count glove's layouts ship beside its recordings)."""
    old = os.environ.get(LAYOUTS_ENV)
    os.environ[LAYOUTS_ENV] = str(folder)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(LAYOUTS_ENV, None)
        else:
            os.environ[LAYOUTS_ENV] = old


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished children (an ingest's worker processes, once reaped)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def glove_only_row(work: Path, reps: int, recording: tuple[str, str, Path, Path] | None = None) -> dict:
    """A glove-only recording (no video, so nothing but tactile to decode) ingested with maps stored and with
    maps = "raw", 1 worker, alternating `reps` times (medians): the EXR encode's whole cost, with no RGB
    decode to hide it. Bytes per frame for both. CPU seconds (this process and the ingest's workers) beside
    the wall-clock speed: on a shared machine the encode threads may find no spare core, and the CPU the
    maps cost is the part of the ratio that load does not move. Then where the stored run's extra time
    goes per frame and what would reach the target (mapcost.py).

    `recording`: (name of its datasets under `work`, label, native recordings folder, layouts folder);
    None: the sample raw-count glove.
    """
    if recording is None:
        src = work / "rawglove_src"
        if not (src / "truth.json").exists():
            write_rawglove(src)
        recording = ("glove_only", "raw-count glove, no video (htdata/synthetic/rawglove.py)", src, src / "layouts")
    tag, label, src, layouts = recording
    runs: dict[str, list[dict]] = {"stored": [], "raw": []}
    with _layouts_on_path(layouts):
        for _ in range(max(1, reps)):
            for choice in runs:
                before = _cpu_s()
                run = ingest_run([("native", src)], work / f"{tag}_{choice}", 1, (f"tactile.maps={choice}",))
                runs[choice].append({**run, "cpu_s": _cpu_s() - before})
        sizes = {c: bytes_per_frame(work / f"{tag}_{c}") for c in runs}
    med = {c: {k: statistics.median(r[k] for r in rs) for k in ("frames_per_s", "worker_s", "cpu_s")}
           for c, rs in runs.items()}
    row = {"recording": label, "frames": runs["raw"][0]["frames"],
           "reps": max(1, reps), "frames_per_s_stored": med["stored"]["frames_per_s"],
           "frames_per_s_raw": med["raw"]["frames_per_s"],
           "speed_ratio": med["stored"]["frames_per_s"] / med["raw"]["frames_per_s"],
           "cpu_s_stored": med["stored"]["cpu_s"], "cpu_s_raw": med["raw"]["cpu_s"],
           "worker_s_stored": med["stored"]["worker_s"], "worker_s_raw": med["raw"]["worker_s"],
           "encode_s_stored": statistics.median(r["stages_s"]["encode"] for r in runs["stored"]),
           "rasterise_s_stored": statistics.median(r["stages_s"]["rasterise"] for r in runs["stored"]),
           "bytes_per_frame_stored": sizes["stored"]["total"], "bytes_per_frame_raw": sizes["raw"]["total"]}
    pixel_type = DatasetReader(work / f"{tag}_stored").manifest["codec"]["tactile"].get("pixel_type", "half")
    row["costs"] = encode_costs(stored_maps(work / f"{tag}_stored"), pixel_type, reps=max(1, reps))
    row["projections"] = projections(row, row["costs"])
    return row


def real_glove_row(folder: Path | None, work: Path, reps: int, quick: bool) -> dict:
    """`glove_only_row` on the real clips of a real-glove folder given by an explicit path (htdata bench
    --real-glove DIR), written as native glove-only recordings; quick: the 3 shortest clips."""
    if folder is None:
        return {"skipped": "no real-glove folder given (htdata bench --real-glove DIR)"}
    clips, layouts = load_real_glove(folder)
    if quick:
        clips = sorted(clips, key=lambda c: len(c.counts))[:3]
    rec_dir = write_native_clips(clips, layouts, work / "maps_realglove")
    label = f"{len(clips)} real clips, no video ({folder})"
    return glove_only_row(work, reps, ("glove_only_real", label, rec_dir, work / "maps_realglove" / "layouts"))


def maps_rows(corpus: Path, work: Path, adapters: tuple[str, ...], quick: bool, real_glove: Path | None = None) -> dict:
    rows = [adapter_row(name, corpus / name, work, 60 if quick else 400, 1 if quick else 3) for name in adapters]
    default, why = pick_default(rows)
    t = TactileConfig()   # what "auto" (the default) resolves to for a new dataset of the shipped pipelines
    return {"rows": rows, "rule": RULE, "default": default, "why": why, "pipeline_setting": t.maps.value,
            "pipeline_default": t.maps.resolved(None).record,
            "frames_at_scale": FRAMES_AT_SCALE, "glove_only": glove_only_row(work, 1 if quick else 3),
            "glove_only_real": real_glove_row(real_glove, work, 1 if quick else 3, quick)}


def maps_markdown(d: dict) -> list[str]:
    lines = ["Bytes per frame by member kind, maps stored / not stored (same episodes, 1 worker):", ""]
    bytes_rows = [{"adapter": r["adapter"], **{k: f"{fmt(r['bytes_stored'][k])} / {fmt(r['bytes_raw'][k])}"
                                               for k, _ in KINDS + (("total", "total"),)},
                   "saving": f"{r['saving']:.0%}", "gb": f"{r['gb_at_10m_stored']:.0f} / {r['gb_at_10m_raw']:.0f}"}
                  for r in d["rows"]]
    lines += table(bytes_rows, [("adapter", "adapter"), *KINDS, ("total", "total B/frame"), ("saving", "saved"),
                                ("gb", f"GB at {d['frames_at_scale'] / 1e6:.0f}M frames")])
    lines += ["Read speed, stored maps decoded vs rendered from raw rows (alternating runs, medians):", ""]
    lines += table(d["rows"], [("adapter", "adapter"), ("frame_items_per_s_stored", "TactileFrameDataset items/s, stored"),
                               ("frame_items_per_s_rendered", "items/s, rendered"), ("frame_ratio", "ratio"),
                               ("decoded_samples_per_s_stored", "decoded() samples/s, stored"),
                               ("decoded_samples_per_s_rendered", "samples/s, rendered"), ("decoded_ratio", "ratio"),
                               ("maps_checked_against_ingest", "maps checked"),
                               ("max_abs_difference", "max |rendered - ingest's map|"),
                               ("stored_over_rendered_difference", "max |stored - rendered|"),
                               ("stored_pixel_type", "stored EXR pixels")])
    if "glove_only" in d:
        rows = [d["glove_only"]] + [r for r in (d.get("glove_only_real"),) if r and "skipped" not in r]
        lines += ["Glove-only recordings, maps stored vs maps = \"raw\" (1 worker, alternating runs, medians; "
                  "target: stored >= 0.8x the raw speed):", ""]
        lines += table(rows, [("recording", "recording"), ("frames", "frames"),
                              ("frames_per_s_stored", "frames/s, stored"),
                              ("frames_per_s_raw", "frames/s, raw"), ("speed_ratio", "stored / raw"),
                              ("cpu_s_stored", "CPU s, stored"), ("cpu_s_raw", "CPU s, raw"),
                              ("worker_s_stored", "in-worker s, stored"), ("worker_s_raw", "in-worker s, raw"),
                              ("encode_s_stored", "encode wait s, stored"),
                              ("rasterise_s_stored", "rasterise s, stored"),
                              ("bytes_per_frame_stored", "B/frame, stored"),
                              ("bytes_per_frame_raw", "B/frame, raw")])
        if "skipped" in (d.get("glove_only_real") or {}):
            lines += [f"Real clips: not measured ({d['glove_only_real']['skipped']}).", ""]
        lines += glove_cost_markdown([r for r in rows if "projections" in r])
    same = "equals" if d["default"] == d["pipeline_default"] else "DIFFERS FROM"
    lines += ["Exact = every map rendered from raw rows equals, bit for bit, the float32 map the ingest computes "
              "before any codec (the same episodes through EpisodeStream); max |stored - rendered| is the stored "
              "maps' own codec rounding (> 0 where the codec rule stores half floats), not a rendering error.", ""]
    lines += ["Ingest, maps stored vs not (1 worker, one run each: no EXR encode when the maps are not stored):", ""]
    lines += table(d["rows"], [("adapter", "adapter"), ("ingest_frames_per_s_stored", "ingest frames/s, stored"),
                               ("ingest_frames_per_s_raw", "frames/s, not stored"),
                               ("ingest_encode_s_stored", "encode s, stored"), ("ingest_encode_s_raw", "encode s, not stored")])
    return lines + [f"**Default: {d['default']}** (computed from the tables above) — rule: {d['rule']}. "
                    f"Measured: {d['why']}.",
                    f"The pipeline's default (`[tactile] maps = \"{d.get('pipeline_setting', 'auto')}\"`, for a new "
                    f"dataset: \"{d['pipeline_default']}\"; an append keeps the "
                    f"parent version's choice) {same} the rule's pick.", ""]
