"""Sensors (warnings only): what the decoded tactile maps of each episode hand say about the glove.

The content check feeds `accumulate` one decoded map at a time (in the shard
workers); `merge_sensor` joins the workers' accumulators; `check_sensors`
warns about regions (canonical region map within coverage) whose mean never
changes over an episode's decoded frames (unexercised if always 0: never
pressed or dead, the maps cannot tell; stuck otherwise; named by place), a saturated fraction above SATURATED_WARN_FRACTION, and hands
whose every decoded map is all zero. The accumulator also collects the
contact-area and pressure histograms of the report's stats.
`check_taxel_health` warns about episode hands with many faulty taxels
(htdata/glove/health.py), from the stats cache or, with --deep, computed.
`check_rest_level` FAILS ("rest_level") an episode hand of raw counts
(NormaliseConfig.raw_counts) whose config subtracts no rest (baseline "none") and whose covered pixels
never read below REST_FAIL_LEVEL: its rest level (~557 of 1023 on a knit
glove) is read as pressure in every frame; the message names the setting.

Accumulator: {hand_key(episode, hand): {"frames", "region_means", "max",
"saturated", "covered"}, "_contact_area": [fractions], "_pressure_hist": counts}.
"""

from __future__ import annotations

import warnings

import numpy as np

from htdata.glove.glovevalue import toward_pressure
from htdata.glove.health import WARN_SHARE, flagged_share
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.inspect.stats import cached_episode_stats, episode_stats
from htdata.read.reader import DatasetReader
from htdata.validate.geometry import CoverageGeometry
from htdata.validate.report import Check

CONTACT_THRESHOLD = 0.02      # a pixel above this counts towards contact area
SATURATION_LEVEL = 0.999      # half precision: 1.0 is exact, 0.999 leaves round-off room
SATURATED_WARN_FRACTION = 0.05
HIST_BINS = 20
REST_FAIL_LEVEL = 0.1         # with baseline "none": the quietest frame's mean covered value at or above this


def hand_key(episode_id: str, hand: str) -> str:
    """Key of per-(episode, hand) dicts: coverage maps, geometry and sensor accumulators."""
    return f"{episode_id}:{hand}"


def region_means(covered_values: np.ndarray, geo: CoverageGeometry) -> np.ndarray:
    """Mean value per region id over covered pixels; NaN for a region with no covered pixel."""
    sums = np.bincount(geo.labels, weights=covered_values, minlength=geo.counts.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(geo.counts > 0, sums / np.maximum(geo.counts, 1), np.nan)
    means[0] = np.nan  # label 0: covered but outside the template's regions
    return means


def value_histogram(values: np.ndarray) -> np.ndarray:
    """HIST_BINS equal bins over [0,1] (1.0 in the last bin), like np.histogram but ~5x cheaper."""
    bins = np.minimum((values * HIST_BINS).astype(np.intp), HIST_BINS - 1)
    return np.bincount(bins, minlength=HIST_BINS)


def accumulate(sensor: dict, episode: str, hand: str, frame: int, covered: np.ndarray,
               geo: CoverageGeometry, peak: float) -> None:
    """Add one decoded map (`covered`: its values at the covered pixels, `peak`: its maximum)."""
    acc = sensor.setdefault(hand_key(episode, hand), {
        "frames": [], "region_means": [], "max": 0.0, "saturated": 0, "covered": 0})
    acc["frames"].append(frame)
    acc["region_means"].append(region_means(covered, geo))
    acc["max"] = max(acc["max"], peak)
    acc["saturated"] += int(np.count_nonzero(covered >= SATURATION_LEVEL))
    acc["covered"] += geo.n_covered
    sensor.setdefault("_contact_area", []).append(
        float(np.count_nonzero(covered > CONTACT_THRESHOLD)) / max(geo.n_covered, 1))
    sensor.setdefault("_pressure_hist", np.zeros(HIST_BINS, np.int64))
    sensor["_pressure_hist"] += value_histogram(covered[covered > 0])


def merge_sensor(into: dict, part: dict) -> None:
    """Join a worker's accumulator into `into` (an episode may span two shards)."""
    for k, v in part.items():
        if k == "_contact_area":
            into.setdefault(k, []).extend(v)
        elif k == "_pressure_hist":
            into[k] = into.get(k, 0) + v
        elif k in into:
            acc = into[k]
            acc["frames"] += v["frames"]
            acc["region_means"] += v["region_means"]
            acc["max"] = max(acc["max"], v["max"])
            acc["saturated"] += v["saturated"]
            acc["covered"] += v["covered"]
        else:
            into[k] = v


def check_sensors(sensor: dict, check: Check, region_names: dict[int, str] | None = None) -> None:
    """Warnings per episode hand; `region_names` (canonical region id -> place name) names regions."""
    for name in sorted(k for k in sensor if not k.startswith("_")):
        eid, hand = name.rsplit(":", 1)
        acc = sensor[name]
        check.checked["episode_hands"] += 1
        where = {"episode": eid, "hand": hand}
        if acc["max"] == 0.0:
            check.warn("all_zero", f"episode {eid}: every decoded {hand} tactile map is all zero "
                       f"({len(acc['frames'])} frames)", **where, count=len(acc["frames"]))
            continue
        frac = acc["saturated"] / max(acc["covered"], 1)
        if frac > SATURATED_WARN_FRACTION:
            check.warn("saturated", f"episode {eid}: {frac:.1%} of covered {hand} pixels saturated",
                       **where, found=round(frac, 4))
        if len(acc["region_means"]) >= 2:
            _check_regions(np.stack(acc["region_means"]), eid, hand, where, check, region_names or {})


def check_rest_level(sensor: dict, episodes: list[dict], calibrations: dict, check: Check) -> None:
    """Fail raw-count episode hands with baseline "none" that read >= REST_FAIL_LEVEL in their quietest frame."""
    by_id = {ep["episode_id"]: ep for ep in episodes}
    for name in sorted(k for k in sensor if not k.startswith("_")):
        eid, hand = name.rsplit(":", 1)
        cal = calibrations.get((by_id.get(eid, {}).get("calibration") or {}).get(hand, ""), {})
        cfg = NormaliseConfig.from_record(cal)      # the rules are the config's (raw_counts, subtracts_rest)
        if not cfg.raw_counts or cfg.subtracts_rest or not sensor[name]["region_means"]:
            continue
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)      # a frame with no region: skipped
            rest = float(np.nanmin(np.nanmean(np.stack(sensor[name]["region_means"])[:, 1:], axis=1)))
        if rest >= REST_FAIL_LEVEL:
            lid, top = cal.get("layout", "?"), float(cfg.max_value)
            raw = rest * top / float(cfg.scale)
            raw = float(toward_pressure(raw, cfg.convention, top))
            check.fail("rest_level", f"episode {eid}: {hand} hand (layout {lid}): rest level {raw:.4g} of {top:g}: "
                       f"covered pixels read >= {rest:.2f} even in the quietest frame with baseline = \"none\" "
                       f"(the rest is read as pressure); set a baseline "
                       f"(drop the baseline line from [normalise.{lid}] for the raw-count default: baseline = "
                       f"\"drift\", noise_k = 5) and renormalise",
                       episode=eid, hand=hand, found=round(rest, 4))


def check_taxel_health(root, version: int | None, check: Check, compute: bool = False) -> None:
    """Warn ("taxel_health") for episode hands whose share of faulty taxels passes health.WARN_SHARE.

    Health comes from the stats cache (`htdata stats`, DATASET/stats/); with
    `compute` (validate --deep) episodes without an entry are computed here
    (nothing is written). Otherwise they are counted as skipped.
    """

    with DatasetReader(root, version=version) as reader:
        cached = cached_episode_stats(reader)
        missing = [p for p in range(len(reader.episodes)) if p not in cached]
        if compute and missing:
            try:
                cached.update(zip(missing, episode_stats(reader, missing, cache_dir=None)[0]))
                missing = []
            except (ValueError, OSError, KeyError) as exc:   # the content check reports unreadable samples
                check.skipped.append(f"taxel health not computed: {exc}")
                return
        if missing:
            check.skipped.append(f"taxel health: {len(missing)} of {len(reader.episodes)} episodes have no "
                                 f"cached stats (run `htdata stats` or validate --deep)")
        for pos in sorted(cached):
            eid = reader.episodes[pos]["episode_id"]
            for hand, h in cached[pos]["hands"].items():
                health = h["health"]
                if not health.get("assessed"):
                    continue
                check.checked["taxel_health_hands"] += 1
                share = flagged_share(health)
                if share > WARN_SHARE:
                    found = {k: v for k, v in health["counts"].items() if v}
                    check.warn("taxel_health", f"episode {eid}: {share:.1%} of the {health['live']} live {hand} "
                               f"taxels look faulty ({', '.join(f'{k} {v}' for k, v in found.items())}; "
                               f"htdata stats --health OUT.png draws them)", episode=eid, hand=hand,
                               found=found, share=round(share, 4))


def _check_regions(means: np.ndarray, eid: str, hand: str, where: dict, check: Check,
                   names: dict[int, str]) -> None:
    """`means`: (frames, regions+1) region means of one episode hand; constant regions warn.

    A region that reads 0 in every frame was never pressed, or its sensors are dead: the maps cannot tell
    which (an idle finger is not a fault), so it is "unexercised"; taxel health (`htdata stats --health`,
    from the raw rows) tells dead taxels apart.
    """
    valid = np.isfinite(means).all(axis=0)
    valid[0] = False
    constant = valid & (np.ptp(np.where(np.isfinite(means), means, 0), axis=0) == 0)
    quiet = np.flatnonzero(constant & (means[0] == 0))
    stuck = np.flatnonzero(constant & (means[0] != 0))

    def named(ids) -> list[str]:
        return [names.get(int(i), f"region {int(i)}") for i in ids]

    if quiet.size:
        check.warn("unexercised_regions", f"episode {eid}: {quiet.size} {hand} region(s) read 0 in all "
                   f"{len(means)} frames (never pressed, or dead: htdata stats --health tells them apart): "
                   f"{', '.join(named(quiet))}", **where, count=int(quiet.size), regions=named(quiet))
    if stuck.size:
        check.warn("stuck_regions", f"episode {eid}: {stuck.size} {hand} region(s) never change "
                   f"over {len(means)} frames: {', '.join(named(stuck))}", **where,
                   count=int(stuck.size), regions=named(stuck))
