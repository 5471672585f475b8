"""Committing an ingest as a new version: the parent's kept parts + this run's units.

Layouts come from the unit records (the document each unit used, see
unit.layout_entry), so nothing is re-resolved here; each layout's coverage is
made from its document under the run's raster mode, as the units made it; the codec block comes from
the pipelines' shared settings (plan.check_settings_agree made them equal,
`check_compatible` made them equal to the parent's). Each unit's index rows come as one array
(`unit_part`, made where the unit ran): the commit checks and concatenates arrays, never a
Python object per sample.
"""

from __future__ import annotations

import hashlib
import json

from htdata.errors import ConfigError, DatasetError
from htdata.format.codec import DEFAULT_CODEC_INFO
from htdata.format.mapstorage import MapStorage
from htdata.glove.codecrule import codec_block
from htdata.glove.layouts import load_canonical, parse_layout
from htdata.ingest.append import parent_parts
from htdata.ingest.episode import rasteriser_for
from htdata.ingest.pipeline import PipelineConfig
from htdata.ingest.workdir import decode_rows
from htdata.store.manifest import CanonicalArtifact, LayoutArtifact, write_layout_files
from htdata.store.parts import Part, part_from_rows
from htdata.write.newversion import NewVersion


def codec_info(cfg: PipelineConfig) -> dict:
    """The manifest's "codec" block for a pipeline's settings."""
    codec = json.loads(json.dumps(DEFAULT_CODEC_INFO))
    codec["tactile"]["compression"] = cfg.tactile.compression
    codec["tactile"]["raster_mode"] = cfg.tactile.raster_mode
    codec["tactile"]["maps"] = cfg.tactile.maps.record   # the driver resolved it before the units ran
    codec["rgb"]["quality"] = cfg.rgb.quality
    codec["rgb"]["crop"] = cfg.rgb.crop
    codec["rgb"]["interpolation"] = cfg.rgb.interpolation
    return codec_block(codec, cfg.codec_choice())


def unit_part(record: dict) -> Part:
    """A unit record's Part: its index rows as the unit made them (arrays, checked vectorised)."""
    where = f"work unit {record['unit']}"
    return part_from_rows(record["unit"], record["shards"], decode_rows(record["rows"], where), record["episodes"],
                          records_checked=True)   # the unit checked them (unit.check_records)


def layout_artifacts(records: list[dict], raster_mode: str, canonical) -> list[LayoutArtifact]:
    """One artefact per layout id the ingested episodes use, sorted by id, from the unit records."""
    used = sorted({lid for r in records for ep in r["episodes"] for lid in ep["layouts"].values()})
    found: dict[str, dict] = {}
    for r in records:
        for lid, entry in r["layouts"].items():
            first = found.setdefault(lid, entry)
            if first["document"] != entry["document"]:
                raise DatasetError(f"layout {lid!r} differs between work units {found_unit(records, lid)} "
                                   f"(a layout file changed during the ingest?); re-run the ingest")
    missing = [lid for lid in used if lid not in found]
    if missing:
        raise DatasetError(f"layouts {missing} are used by episodes but no unit record carries them")
    return [LayoutArtifact(layout_id=lid, document=found[lid]["document"], coverage=rasteriser_for(
        parse_layout(found[lid]["document"], f"layout {lid!r} of the unit records", canonical), raster_mode).coverage)
        for lid in used]


def found_unit(records: list[dict], layout_id: str) -> list[int]:
    return [r["unit"] for r in records if layout_id in r["layouts"]]


def check_compatible(parent, sources: list) -> None:
    """Refuse settings a dataset records once (canonical template, codec, raster mode, RGB) that differ
    from the parent version's, naming the setting."""
    if parent is None:
        return
    theirs = MapStorage.comparable_codec(parent.manifest["codec"])   # a version without the record stores its maps
    ours = codec_info(sources[0].pipeline)
    for section in ("tactile", "rgb"):
        for key in sorted(set(theirs.get(section, {})) | set(ours[section])):
            a, b = theirs.get(section, {}).get(key), ours[section].get(key)
            if a != b:
                raise ConfigError(f"{parent.root}: the dataset was written with {section}.{key} = {a!r}, pipeline "
                                  f"{sources[0].pipeline.name!r} asks for {b!r}; a dataset has one codec: use "
                                  f"the dataset's setting or ingest into a new dataset (htdata merge cannot mix "
                                  f"them either)")
    canon = load_canonical()
    doc = (json.dumps(canon.to_dict(), indent=2, sort_keys=True) + "\n").encode()
    if hashlib.sha256(doc).hexdigest() != parent.manifest["canonical"]["sha256"]:
        raise DatasetError(f"{parent.root}: the dataset was written with another canonical hand template "
                           f"(sha256 {parent.manifest['canonical']['sha256'][:12]}); its maps are not comparable "
                           f"with this htdata's: ingest into a new dataset")


def merged_sources(parent, sources: list) -> list[dict]:
    """The parent's source entries plus this run's (a pipeline + root already listed is replaced)."""
    new = [{**s.pipeline.to_dict(), "source_root": str(s.root)} for s in sources]
    keys = {(d["name"], d["source_root"]) for d in new}
    old = [d for d in (parent.manifest["sources"] if parent else [])
           if (d.get("name"), d.get("source_root")) not in keys]
    return old + new


def commit(nv: NewVersion, sources: list, records: list[dict], plan) -> dict:
    """Write the new version in the ingest's transaction `nv`: the parent's parts (minus replaced episodes)
    then this run's units."""
    out = nv.root
    canon = load_canonical()
    canonical = CanonicalArtifact(document=canon.to_dict(), region_map=canon.region_map, part_map=canon.part_map)
    artifacts = layout_artifacts(records, sources[0].pipeline.tactile.raster_mode, canon)
    layout_entries, canonical_entry = write_layout_files(out, artifacts, canonical)
    ingested = {ep["episode_id"] for r in records for ep in r["episodes"]}
    nv.skip_to(max([nv.first_unit] + [r["unit"] + 1 for r in records]))   # the run's units are taken
    kept = parent_parts(plan, ingested, nv)
    parts = kept + [unit_part(r) for r in records if r["episodes"]]
    fields = {"sources": merged_sources(plan.parent, sources), "layouts": layout_entries,
              "canonical": canonical_entry, "codec": codec_info(sources[0].pipeline),
              "calibrations": {k: v for r in records for k, v in r.get("calibrations", {}).items()}}
    return nv.commit(parts, fields)
