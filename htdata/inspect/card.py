"""`htdata card DATASET OUT.html`: a self-contained dataset card (HTML + a Markdown twin), plots drawn with cv2.

The card opens with what a dataset card has (name, description, licence, sources, the sample
format, how to load it), then holds the `htdata stats` numbers of one version and these plots:
frames per task and per scene, the contact frequency of each canonical
region per glove (drawn on the canonical hand), the value histogram per
glove (over a range fitted to its values, htdata/inspect/cardplots.py), the
suggested `scale` per glove layout (htdata/inspect/scalehint.py), the taxel
health map, the sync skew, clock-offset and lag distributions (episode
records' "sync"), the split sizes, and preview strips of a few episodes. A
glove-only dataset (no RGB in any sample) says so and lists no rgb.jpg member. Every image is a PNG embedded as a data: URI and there is no
script, stylesheet or font from elsewhere, so the page opens offline. The
Markdown twin (OUT.md) has the same tables and links the same PNGs written
to OUT_files/.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic
from htdata.format.mapstorage import MapStorage
from htdata.format.table import HANDS, RGB_MEMBER, SIZE_FIELDS
from htdata.glove.canonical import parse_canonical
from htdata.inspect.cardplots import (
    bar_chart,
    histogram_chart,
    region_heatmap,
    value_histogram_chart,
)
from htdata.inspect.preview import render_contact_sheet
from htdata.inspect.stats import dataset_stats, write_health_map
from htdata.read.reader import DatasetReader
from htdata.store import storage

PREVIEW_EPISODES = 2
PREVIEW_FRAMES = 3


@dataclass
class Card:
    """The card's parts before they are written: sections of (kind, payload)."""
    title: str
    sections: list = field(default_factory=list)
    images: dict[str, np.ndarray] = field(default_factory=dict)

    def heading(self, text: str) -> None:
        self.sections.append(("h2", text))

    def text(self, text: str) -> None:
        self.sections.append(("p", text))

    def table(self, header: list[str], rows: list[list]) -> None:
        self.sections.append(("table", (header, rows)))

    def image(self, name: str, img: np.ndarray, alt: str) -> None:
        self.images[name] = img
        self.sections.append(("img", (name, alt)))


def _png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError("cv2 could not encode a card image as PNG")
    return buf.tobytes()


def _fmt(v) -> str:
    if v is None:
        return "-"
    return f"{v:.3f}" if isinstance(v, float) else str(v)


LICENSE_UNSET = "not stated (set it with htdata card --license, e.g. CC-BY-4.0)"
def has_rgb(reader) -> bool:
    """Whether any sample of the version holds an RGB frame (from the index: no shard read)."""
    return bool(len(reader) and np.any(reader.index[SIZE_FIELDS[RGB_MEMBER]] > 0))


def sample_format(codec: dict, rgb_frames: bool = True) -> list[list[str]]:
    """The member table, from the dataset's own codec record (the EXR pixel type is chosen per dataset);
    no rgb.jpg row for a dataset without video."""
    tactile, rgb = codec.get("tactile", {}), codec.get("rgb", {})
    stored = MapStorage.from_codec(codec).stores_maps
    return [
        *([["rgb.jpg", f"224x224x3 uint8 JPEG, quality {rgb.get('quality', '?')}", "egocentric camera frame"]]
          if rgb_frames else []),
        ["tactile_<hand>.exr", f"224x224 {tactile.get('pixel_type', 'half')} EXR ({tactile.get('compression', '?')}) "
         "in [0,1]" if stored else "not stored (maps = raw): htdata's readers render it from raw_<hand>.npy",
         "pressure on the canonical hand, 0 where the glove has no sensor"],
        ["raw_<hand>.npy", "the glove's own grid, its source dtype", "the glove rows exactly as recorded"],
        ["json", "per-sample metadata", "episode, frame, timestamps, sync offsets, hands present"],
    ]


def _about(card: Card, s: dict, reader, title: str | None, description: str | None,
           license: str | None) -> None:
    """What a dataset card opens with: name, description, licence, sources, sample format, how to load."""
    manifest = reader.manifest
    rgb = has_rgb(reader)
    card.text(description or manifest.get("description") or
              f"Full-hand tactile glove recordings {'paired with egocentric RGB video' if rgb else '(glove only, no video)'}"
              f": {s['episodes']} episodes, {s['frames']} frames, {len(s['tasks'])} tasks.")
    card.table(["field", "value"], [["licence", license or manifest.get("license") or LICENSE_UNSET],
                                    ["version", s["version"]], ["episodes", s["episodes"]], ["frames", s["frames"]],
                                    ["created", manifest.get("created", "-")]])
    card.heading("Sources")
    card.table(["source", "adapter", "gloves (hand: layout)", "episodes"], source_rows(manifest, reader.episodes))
    card.heading("Sample format")
    card.text("One sample per frame; a frame without a glove row (RGB-only) or without video (tactile-only) "
              "simply lacks that member." if rgb else
              "One sample per glove frame (glove only: no camera, so no rgb.jpg member).")
    card.table(["member", "format", "what"], sample_format(manifest.get("codec", {}), rgb))
    card.heading("How to load")
    card.text("Install htdata from its source folder (no package index serves it): pip install . in the "
              "htdata checkout; then in Python: import htdata; ds = htdata.open(\"PATH\"); "
              "sample = ds.decoded(0). For LeRobot: htdata export lerobot PATH OUT.")


def source_rows(manifest: dict, episodes: list[dict]) -> list[list]:
    """Sources table rows: name, adapter, the gloves its episodes use, its episodes.

    An episode record names its ADAPTER ("source"), a manifest source its pipeline's name: an episode
    belongs to the source whose folder holds its source_ref, else to the one of its name or adapter.
    """
    sources = manifest.get("sources", [])
    counts = [0] * len(sources)
    gloves: list[dict] = [dict(src.get("layouts") or {}) for src in sources]

    def owner(ep: dict) -> int | None:
        ref, name = str(ep.get("source_ref", "")), ep.get("source")
        for test in (lambda s: s.get("source_root") and ref.startswith(str(s["source_root"]).rstrip("/") + "/"),
                     lambda s: s.get("name") == name, lambda s: (s.get("adapter") or {}).get("name") == name):
            hits = [k for k, src in enumerate(sources) if test(src)]
            if hits:
                return hits[0]
        return None

    for ep in episodes:
        k = owner(ep)
        if k is not None:
            counts[k] += 1
            for hand, lid in ep.get("layouts", {}).items():
                gloves[k].setdefault(hand, lid)
    return [[src.get("name", "?"), (src.get("adapter") or {}).get("name", "-"),
             ", ".join(f"{h}: {lid}" for h, lid in sorted(gloves[k].items())) or "-", counts[k]]
            for k, src in enumerate(sources)]


def build_card(root, version: int | None = None, title: str | None = None, description: str | None = None,
               license: str | None = None) -> Card:
    """Numbers and plots of one version (stats computed or read from the stats cache)."""

    s = dataset_stats(root, version=version)
    card = Card(title=f"{title or Path(str(root)).name}: version {s['version']}")
    card.text(f"{s['episodes']} episodes, {s['frames']} frames. Values: {s['values']}; "
              f"contact per glove and hand from its calibration (the rule of each glove is "
              f"in the Gloves table; 'old contact' = any taxel above {s['contact_threshold']}).")
    with DatasetReader(root, version=version) as reader:
        _about(card, s, reader, title, description, license)   # the values are said once, in the opening line
        card.heading("What the numbers mean")
        rules = s.get("contact_rules") or ["-"]
        card.text("Contact (htdata/glove/contact.py, from each glove hand's calibration): "
                  + ("a frame with " + rules[0] if len(rules) == 1 else
                     "per glove, the rule in the Gloves table (" + "; ".join(rules) + ")") + ".")
        _counts(card, s)
        _gloves(card, s, reader, parse_canonical)
        card.heading("Taxel health")
        card.text("Fault classes per taxel (htdata/glove/health.py); a taxel gets the class it was given most often.")
        if s["gloves"]:
            import tempfile
            with tempfile.TemporaryDirectory() as tmp:
                png = write_health_map(root, Path(tmp) / "health.png", version=version)
                card.image("health", cv2.imread(str(png)), "taxel health map")
        _sync(card, reader)
        _splits(card, reader)
        _previews(card, root, reader)
    return card


def _counts(card: Card, s: dict) -> None:
    card.heading("Tasks and scenes")
    for field_name, table in (("task", s["tasks"]), ("scene", s["scenes"])):
        card.table([field_name, "episodes", "frames", "duration (s)", "left hand eps", "right hand eps"],
                   [[k, r["episodes"], r["frames"], r["duration_s"], r["hands"]["left"], r["hands"]["right"]]
                    for k, r in table.items()])
        card.image(f"frames_per_{field_name}", bar_chart(list(table), [r["frames"] for r in table.values()],
                                                         f"frames per {field_name}"), f"frames per {field_name}")


def _gloves(card: Card, s: dict, reader, parse_canonical) -> None:
    import json
    card.heading("Gloves")
    card.table(["layout", "hand", "episodes", "frames", "contact", "contact rule", "old contact", "p1", "p50",
                "p99", "max", "faulty taxels"],
               [[g["layout"], g["hand"], g["episodes"], g["frames"], _fmt(g["contact_fraction"]),
                 g.get("contact_rule") or "-", _fmt(g.get("contact_fraction_threshold")),
                 *(_fmt(g["quantiles"][k]) for k in ("p1", "p50", "p99", "max")),
                 sum(g["health"]["counts"].values())] for g in s["gloves"]])
    canon_file = reader.manifest["canonical"]["file"]
    canonical = parse_canonical(json.loads(storage.read_text(storage.join(reader.root, canon_file))), canon_file)
    for g in s["gloves"]:
        tag = f"{g['hand']}_{g['layout']}"
        card.image(f"regions_{tag}", region_heatmap(g, canonical.region_map, canonical.region_ids,
                                                    f"{g['hand']}: {g['layout']}"),
                   f"contact frequency per region, {g['hand']} {g['layout']}")
        card.image(f"values_{tag}", value_histogram_chart(g["value_histogram"], f"{g['hand']} {g['layout']}"),
                   f"value histogram, {g['hand']} {g['layout']}")
    hints = s.get("scale") or {}
    if hints:
        card.text("Scale (htdata/inspect/scalehint.py): per glove layout, the p99.9 of its pressed values and, "
                  "where the maps use less than half of 0..1, a suggested `scale` for the pipeline TOML.")
        card.table(["layout", "pressed values", "p99.9", "scale", "suggestion"],
                   [[lid, h["pressed"], _fmt(h["p99_9"]), _fmt(h["scale"]),
                     h["toml"].replace("\n", " ") if h.get("toml") else h.get("reason", "-")]
                    for lid, h in hints.items()])


def _sync(card: Card, reader) -> None:
    skew, offset = [], []
    glove_only = sum(bool(ep.get("tactile_only")) for ep in reader.episodes)
    for ep in reader.episodes:
        if ep.get("tactile_only"):     # no video: its frames run on the glove's own clock, nothing to sync
            continue
        for hand in HANDS:
            h = (ep.get("sync") or {}).get("hands", {}).get(hand)
            if h:
                skew.append(h.get("median_abs_skew_ns", 0) / 1e6)
                offset.append(h.get("offset_ns", 0) / 1e6)
    card.heading("Synchronisation")
    card.text(f"{len(skew)} episode hands with sync records: median |RGB-tactile skew| and clock offset (ms)."
              + (f" {glove_only} glove-only episode(s) (no video) have none." if glove_only else ""))
    lags = [lag for lag in ((ep.get("sync") or {}).get("lag") for ep in reader.episodes) if lag]
    applied = [float(lag["lag_ms"]) for lag in lags if lag.get("applied")]
    if lags:   # only pipelines with [sync] lag set report one (htdata/source/lag.py)
        card.text(f"Tactile-video lag ([sync] lag): {len(lags)} episodes asked, {len(applied)} applied"
                  + (f" (median {np.median(applied):.1f} ms)" if applied else "")
                  + f", {len(lags) - len(applied)} declined.")
    for key, name, values in (("skew", "median |skew| (ms)", skew), ("clock", "clock offset (ms)", offset),
                              ("lag", "applied lag (ms)", applied)):
        if values:
            lo, hi = float(min(values)), float(max(values))
            hi = hi if hi > lo else lo + 1.0
            counts = np.histogram(values, bins=30, range=(lo, hi))[0].tolist()
            card.image(f"sync_{key}", histogram_chart(counts, round(lo, 3), round(hi, 3), name, log=False), name)


def _splits(card: Card, reader) -> None:
    card.heading("Splits")
    names = sorted(reader.manifest.get("splits", {}))
    if not names:
        card.text("No split in this version (htdata split).")
    for name in names:
        parts = reader.split(name)["parts"]
        rows = []
        for part, doc in sorted(parts.items()):
            pos = reader.episode_positions(name, part)
            rows.append([part, len(pos), sum(reader.episode_range(p)[1] for p in pos)])
        card.table([f"split {name}: part", "episodes", "frames"], rows)


def _previews(card: Card, root, reader) -> None:
    card.heading("Previews")
    by_contact = sorted(reader.episodes, key=lambda e: -max((e.get("stats") or {}).get("mean_contact", {0: 0}).values()
                                                          or [0]))
    for ep in by_contact[:PREVIEW_EPISODES]:
        sheet = render_contact_sheet(root, episode=ep["episode_id"], frames=PREVIEW_FRAMES, contrast="quantile")
        card.image(f"preview_{len(card.images)}", cv2.resize(sheet, None, fx=0.6, fy=0.6, interpolation=cv2.INTER_AREA),
                   f"preview of {ep['episode_id']}")


def render_html(card: Card) -> str:
    e = html.escape
    out = ["<!doctype html>", '<html lang="en"><head><meta charset="utf-8">', f"<title>{e(card.title)}</title>",
           "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
           "table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 8px;"
           "text-align:right}th{background:#eee}img{display:block;margin:.5em 0;max-width:100%}</style>",
           "</head><body>", f"<h1>{e(card.title)}</h1>"]
    for kind, payload in card.sections:
        if kind in ("h2", "p"):
            out.append(f"<{kind}>{e(payload)}</{kind}>")
        elif kind == "table":
            header, rows = payload
            out.append("<table><tr>" + "".join(f"<th>{e(str(h))}</th>" for h in header) + "</tr>")
            out += ["<tr>" + "".join(f"<td>{e(str(v))}</td>" for v in row) + "</tr>" for row in rows]
            out.append("</table>")
        else:
            name, alt = payload
            data = base64.b64encode(_png(card.images[name])).decode("ascii")
            out.append(f'<img alt="{e(alt)}" src="data:image/png;base64,{data}">')
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def render_markdown(card: Card, files_dir: str) -> str:
    out = [f"# {card.title}", ""]
    for kind, payload in card.sections:
        if kind == "h2":
            out += [f"## {payload}", ""]
        elif kind == "p":
            out += [payload, ""]
        elif kind == "table":
            header, rows = payload
            out.append("| " + " | ".join(str(h) for h in header) + " |")
            out.append("|" + "---|" * len(header))
            out += ["| " + " | ".join(str(v) for v in row) + " |" for row in rows]
            out.append("")
        else:
            name, alt = payload
            out += [f"![{alt}]({files_dir}/{name}.png)", ""]
    return "\n".join(out)


def write_card(root, out, version: int | None = None, title: str | None = None, description: str | None = None,
               license: str | None = None) -> tuple[Path, Path]:
    """Write OUT.html (self-contained), OUT.md and OUT_files/*.png; returns (html, md) paths."""
    out = Path(out)
    if out.suffix.lower() != ".html":
        raise ArgumentError(f"{out}: the card is written as HTML; give a .html path")
    card = build_card(root, version, title=title, description=description, license=license)
    out.parent.mkdir(parents=True, exist_ok=True)
    files = out.with_name(out.stem + "_files")
    files.mkdir(exist_ok=True)
    for name, img in card.images.items():
        write_bytes_atomic(files / f"{name}.png", _png(img))
    md = out.with_suffix(".md")
    write_bytes_atomic(md, render_markdown(card, files.name).encode("utf-8"))
    write_bytes_atomic(out, render_html(card).encode("utf-8"))
    return out, md
