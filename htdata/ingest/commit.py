"""Committing an ingest: unit records -> layouts/, episodes.jsonl, index.npy, dataset.json (last).

Layouts come from the unit records (document + coverage, see unit.layout_entry),
so nothing is re-resolved or re-rasterised here; the codec block comes from
the pipelines' shared settings (plan.check_settings_agree made them equal).
"""

from __future__ import annotations

import json
from pathlib import Path

from htdata.codec import DEFAULT_CODEC_INFO
from htdata.ingest.unit import decode_coverage
from htdata.layouts import load_canonical
from htdata.manifest import CanonicalArtifact, LayoutArtifact, UnitResult, commit_dataset
from htdata.pipeline import PipelineConfig
from htdata.shardio import SampleRecord, ShardRecord


def codec_info(cfg: PipelineConfig) -> dict:
    """The manifest's "codec" block for a pipeline's settings."""
    codec = json.loads(json.dumps(DEFAULT_CODEC_INFO))
    codec["tactile"]["compression"] = cfg.tactile.compression
    codec["tactile"]["raster_mode"] = cfg.tactile.raster_mode
    codec["rgb"]["quality"] = cfg.rgb.quality
    codec["rgb"]["crop"] = cfg.rgb.crop
    codec["rgb"]["interpolation"] = cfg.rgb.interpolation
    return codec


def unit_result(record: dict) -> UnitResult:
    return UnitResult(unit=record["unit"],
                      shards=[ShardRecord(**s) for s in record["shards"]],
                      samples=[SampleRecord(**s) for s in record["samples"]],
                      episodes=record["episodes"])


def layout_artifacts(records: list[dict]) -> list[LayoutArtifact]:
    """One artefact per layout id the ingested episodes use, sorted by id, from the unit records."""
    used = sorted({lid for r in records for ep in r["episodes"] for lid in ep["layouts"].values()})
    found: dict[str, dict] = {}
    for r in records:
        for lid, entry in r["layouts"].items():
            first = found.setdefault(lid, entry)
            if first["document"] != entry["document"] or first["coverage"] != entry["coverage"]:
                raise ValueError(f"layout {lid!r} differs between work units {found_unit(records, lid)} "
                                 f"(a layout file changed during the ingest?); re-run the ingest")
    missing = [lid for lid in used if lid not in found]
    if missing:
        raise ValueError(f"layouts {missing} are used by episodes but no unit record carries them")
    return [LayoutArtifact(layout_id=lid, document=found[lid]["document"], coverage=decode_coverage(found[lid]["coverage"]))
            for lid in used]


def found_unit(records: list[dict], layout_id: str) -> list[int]:
    return [r["unit"] for r in records if layout_id in r["layouts"]]


def commit(out: Path, sources: list, records: list[dict]) -> dict:
    """Write the dataset's index, episodes, layouts and manifest from the unit records (in unit order)."""
    canon = load_canonical()
    canonical = CanonicalArtifact(document=canon.to_dict(), region_map=canon.region_map, part_map=canon.part_map)
    srcs = [{**s.pipeline.to_dict(), "source_root": str(s.root)} for s in sources]
    return commit_dataset(out, [unit_result(r) for r in records], layout_artifacts(records), canonical,
                          codec_info(sources[0].pipeline), srcs)
