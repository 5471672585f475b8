"""`validate_dataset`: run every check on a committed dataset and return the report."""

from __future__ import annotations

import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from htdata.errors import ArgumentError
from htdata.store import storage
from htdata.validate.calibrations import check_calibration_records, check_taxel_digests, has_taxel_digests
from htdata.validate.content import decode_mask, layout_maps
from htdata.validate.geometry import coverage_geometries
from htdata.validate.loaded import Loaded, load_dataset
from htdata.validate.report import CHECKS, Check
from htdata.validate.sensors import check_rest_level, check_sensors, check_taxel_health, hand_key, merge_sensor
from htdata.validate.served import RenderedCheck, check_served_maps, served_rows
from htdata.validate.shards import run_jobs, shard_jobs
from htdata.validate.splits import check_split_name, check_splits
from htdata.validate.stats import dataset_stats
from htdata.validate.structure import check_index, check_shard_files
from htdata.validate.timestamps import check_time, empty_timestamps, merge_timestamps
from htdata.workers import resolve_workers


@dataclass
class ValidateConfig:
    """The settings of one `htdata validate` run (see `validate_dataset` for each field); `validate()` checks them."""

    split: str | None = None
    deep: bool = False
    sample_frac: float = 0.05
    seed: int = 0
    workers: int | None = None   # htdata/workers.py: None = every usable core for --deep, inline otherwise; 0 inline
    max_listed: int = 1000       # failures listed per check (all are counted)

    def validate(self) -> None:
        if not (0.0 < self.sample_frac <= 1.0):
            raise ArgumentError(f"--sample-frac must be in (0, 1], got {self.sample_frac}")
        resolve_workers(self.workers)    # ArgumentError below 0
        if self.max_listed < 1:
            raise ArgumentError(f"max_listed must be >= 1, got {self.max_listed}")

    def resolved_workers(self, n_shards: int) -> int:
        """Processes over `n_shards` shards: at most one a shard; 1 = inline, in this process (0 asks for that)."""
        wanted = resolve_workers(self.workers, default=None if self.deep else 0)
        return max(1, min(wanted, max(n_shards, 1)))


def validate_dataset(path, split: str | None = None, deep: bool = False, sample_frac: float = 0.05,
                     seed: int = 0, workers: int | None = None, max_listed: int = 1000,
                     version: int | None = None) -> dict:
    """Run every check on a committed dataset's current version (or `version`); returns the report.

    Args:
        path: the dataset folder.
        split: also check this split's files and leak rules (None: the splits the version lists).
        deep: decode every sample (else a `sample_frac` sample of them) and recompute the taxel digests.
        sample_frac: the share of samples decoded when not `deep`, in (0, 1].
        seed: which samples that share is.
        workers: processes for the content checks (htdata/workers.py: None = every usable core for `deep`, else
            none; 0 or 1 = in this process).
        max_listed: failures listed per check (all are counted).
        version: the committed version to check (None: the current one).

    Returns:
        The report (docs/FORMAT.md "validate"): report["ok"] is the verdict, report["checks"] each check.

    Raises:
        ArgumentError: a setting out of range (ValidateConfig.validate), or a `split` the version does not
            have (checked before any sample is read: a typo runs nothing).
    """
    cfg = ValidateConfig(split=split, deep=deep, sample_frac=sample_frac, seed=seed, workers=workers,
                         max_listed=max_listed)
    cfg.validate()
    root = Path(path)
    t0 = time.perf_counter()
    checks = {name: Check(name, cfg.max_listed) for name in CHECKS}
    report = {"dataset": str(root), "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "params": {"split": split, "deep": deep, "sample_frac": sample_frac, "seed": seed,
                         "version": version}}
    ds = load_dataset(root, checks["structure"], version)
    if ds is not None and split is not None:
        check_split_name(ds, split)
    stats: dict = {}
    if ds is not None and check_index(ds, checks["structure"]):
        stats = _check_dataset(ds, cfg, checks, report["params"])
    else:
        for name in CHECKS[1:]:
            checks[name].skipped.append("structure could not be read")
    if split is None:
        checks["splits"].skipped.append("no --split given")
    report["checks"] = {name: c.to_dict() for name, c in checks.items()}
    report["stats"] = stats
    report["ok"] = all(c.ok for c in checks.values())
    report["elapsed_s"] = round(time.perf_counter() - t0, 3)
    report["samples"] = int(len(ds.index)) if ds is not None else 0
    return report


def _check_dataset(ds: Loaded, cfg: ValidateConfig, checks: dict[str, Check], params: dict) -> dict:
    """Everything after a usable index: shards in workers, then time, sensors, splits. Returns the stats."""
    check_shard_files(ds, checks["structure"])
    coverage, region_map = layout_maps(ds.root, ds.manifest, checks["content"])
    decode = decode_mask(ds.index["frame"], cfg.deep, cfg.sample_frac, cfg.seed)
    jobs = shard_jobs(ds, decode, coverage, region_map, content_hash=cfg.split is not None)
    n_workers = cfg.resolved_workers(len(jobs))
    params["workers"] = n_workers
    ts = empty_timestamps(len(ds.index))
    sensor: dict = {}
    hashes: dict[int, str] = {}
    for res in run_jobs(jobs, n_workers):
        checks["structure"].merge(res["structure"])
        checks["content"].merge(res["content"])
        merge_timestamps(ts, res["timestamps"], res["timestamps"]["row"])
        hashes.update(dict(res["hashes"]))
        merge_sensor(sensor, res["sensor"])
    # a version whose calibration records do not match their ids is refused by every reader: nothing is served
    readable = check_calibration_records(ds.root, ds.manifest, ds.episodes, checks["structure"])
    if readable and cfg.deep and has_taxel_digests(ds.episodes):
        check_taxel_digests(ds.root, ds.manifest.get("version"), checks["content"])
    if readable:
        check_served_maps(ds.root, ds.manifest.get("version"), served_rows(decode, ds.index["episode"], cfg.seed),
                          checks["content"], rendered=RenderedCheck(decode, _hand_geometries(ds, coverage, region_map),
                                                                    sensor))
    check_time(ds, ts, checks["time"])
    check_sensors(sensor, checks["sensors"], _region_names(ds))
    check_rest_level(sensor, ds.episodes, ds.manifest.get("calibrations", {}), checks["sensors"])
    if readable:
        check_taxel_health(ds.root, ds.manifest.get("version"), checks["sensors"], compute=cfg.deep)
    if cfg.split is not None:
        check_splits(ds, cfg.split, hashes, checks["splits"])
    return dataset_stats(ds, sensor)


def _region_names(ds) -> dict[int, str]:
    """Canonical region id -> place name, from the dataset's canonical document ({} when unreadable)."""
    import json


    try:
        doc = json.loads(storage.read_text(storage.join(ds.root, ds.manifest["canonical"]["file"])))
        return {int(p["region_id"]): name for name, p in doc.get("places", {}).items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def _hand_geometries(ds: Loaded, coverage: dict, region_map) -> dict:
    """hand_key -> coverage geometry of every episode hand (rendered maps are checked in this process)."""
    by_hand = {hand_key(ep["episode_id"], hand): coverage[lid]
               for ep in ds.episodes for hand, lid in ep["layouts"].items() if lid in coverage}
    return coverage_geometries(by_hand, region_map)
