"""What a LeRobot export will write, decided before any byte is: features, parts, and each row's stored frame.

`plan_export` reads only the manifest and episode records (and a JSON member
per episode for the schedule); `features` is meta/info.json's feature table;
`_episode_schedule` puts an episode's rows on LeRobot's exact 1/fps grid,
each holding the stored frame nearest its tick on the source clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.export.lerobot_window import check_window
from htdata.format.canvas import CANVAS
from htdata.format.table import HANDS, JSON_MEMBER, RGB_MEMBER, SIZE_FIELDS, decode_member
from htdata.read.reader import DatasetReader
from htdata.store import storage

RGB_KEY = "observation.images.egocentric"


PRESENT_KEY = "observation.present"


SOURCE_KEY = "htdata.frame_index"      # which stored frame a row is: the rows sit on a 1/fps grid


def raw_key(hand: str) -> str:
    """The feature name of `hand`'s raw glove rows ("left" / "right")."""
    return f"observation.tactile.{hand}.raw"


def map_key(hand: str) -> str:
    """The video feature name of `hand`'s tactile maps (exported with `maps`)."""
    return f"observation.tactile.{hand}.map"


@dataclass
class LeRobotExportConfig:
    """What `htdata export lerobot` exports and where: one version (or a split part) of `dataset` into `out`."""
    dataset: str
    out: Path
    version: int | None = None
    split: str | None = None
    part: str | None = None
    fps: float | None = None          # None: the episodes' own rate, no resampling
    maps: bool = False
    maps_gain: float = 1.0            # --maps: grey level = clip(value x gain, 0, 1) x 255
    codec: str = "libx264"
    crf: int = 18
    gop: int = 2                      # keyframe every 2 frames: LeRobot's default, cheap random access
    force: bool = False
    tactile_window: int | None = None  # K: each frame also carries the glove rows since the previous frame

    def validate(self) -> None:
        """Raise ArgumentError naming the option (--part, --fps, crf, gop, codec, OUT) that cannot be exported."""
        if self.part is not None and self.split is None:
            raise ArgumentError("--part needs --split NAME")
        check_window(self.tactile_window)
        if not (isinstance(self.maps_gain, (int, float)) and np.isfinite(self.maps_gain) and self.maps_gain > 0):
            raise ArgumentError(f"--maps-gain must be a finite number > 0, got {self.maps_gain!r}")
        if self.fps is not None and not (self.fps > 0 and float(self.fps).is_integer()):
            raise ArgumentError(f"--fps must be a positive whole number (LeRobot's fps is an int), got {self.fps}")
        if not 0 <= self.crf <= 51:
            raise ArgumentError(f"crf must be in 0..51, got {self.crf}")
        if self.gop < 1:
            raise ArgumentError(f"gop must be >= 1, got {self.gop}")
        if self.codec not in ("libx264", "libsvtav1"):
            raise ArgumentError(f"codec must be libx264 or libsvtav1, got {self.codec!r}")
        if storage.is_url(str(self.out)):
            raise ArgumentError(f"{self.out}: the export writes a local directory")


# --------------------------------------------------------------------------- the export
@dataclass(frozen=True)
class RawSlot:
    """One raw feature: a hand's glove rows of one grid shape (a hand recorded with two grid shapes has two)."""
    hand: str
    grid: tuple[int, int]
    key: str                                  # feature name
    name: str                                 # its entry in observation.present's names


@dataclass
class _Plan:
    positions: list[int]                     # htdata episode positions, in export order
    parts: dict[str, list[str]]              # split part -> episode ids (exported ones), in export order
    hands: list[str]
    slots: list[RawSlot]
    layout_grids: dict[str, tuple[int, int]]  # layout id -> raw grid
    layouts: dict[str, list[str]]            # hand -> layout ids used
    fps: int
    resample: bool
    split_doc: dict | None = None
    video_keys: list[str] = field(default_factory=list)
    maps_gain: float = 1.0                   # the map videos' grey level = clip(value x gain) x 255
    rgb: bool = True                         # any exported frame holds RGB: else no egocentric video at all

    @property
    def present_names(self) -> list[str]:
        """observation.present's columns: "egocentric" (when the export has RGB), then each raw slot."""
        return (["egocentric"] if self.rgb else []) + [slot.name for slot in self.slots]

    def present_col(self, k: int) -> int:
        """Column of raw slot k in observation.present."""
        return k + (1 if self.rgb else 0)


def plan_export(reader: DatasetReader, cfg: LeRobotExportConfig) -> _Plan:
    """Which episodes, in which order, with which features; errors name the episode.

    Args:
        reader: the version to export, open.
        cfg: the export's settings (split / part select the episodes, fps a resampling rate, maps the map videos).

    Returns:
        The plan: episode positions in export order, split parts, hands, raw feature slots, layouts,
        fps (and whether rows are resampled to it), video keys, whether any frame holds RGB.

    Raises:
        ValueError: no episode selected, a layout without a raw grid, a dataset of format < 3 (no raw
            rows), or episodes at different frame rates without `cfg.fps`; an unknown split or part
            raises what the reader raises.
    """
    split_doc, parts = None, {}
    if cfg.split is None:
        positions = reader.episode_positions()
    else:
        split_doc = reader.split(cfg.split)
        names = [cfg.part] if cfg.part is not None else list(split_doc["parts"])
        positions = []
        for name in names:
            # each part contiguous in episode order: info.json "splits" can then say "start:end"
            pos = reader.episode_positions(cfg.split, name)
            parts[name] = [reader.episodes[p]["episode_id"] for p in pos]
            positions += pos
    if not positions:
        raise ArgumentError(f"{reader.root}: nothing to export (no episodes selected)")
    hands = [h for h in HANDS if any(h in reader.episodes[p]["hands"] for p in positions)]
    layout_grids: dict[str, tuple[int, int]] = {}
    layouts: dict[str, list[str]] = {}
    for p in positions:
        ep = reader.episodes[p]
        for hand, layout_id in sorted(ep["layouts"].items()):
            if layout_id not in layout_grids:
                grid = reader.layout(layout_id).get("grid")
                if not grid or len(grid) != 2:
                    raise DatasetError(f"episode {ep['episode_id']!r}: layout {layout_id!r} names no raw grid")
                layout_grids[layout_id] = (int(grid[0]), int(grid[1]))
            if layout_id not in layouts.setdefault(hand, []):
                layouts[hand].append(layout_id)
    slots = []
    for hand in hands:
        grids = list(dict.fromkeys(layout_grids[lid] for lid in layouts.get(hand, [])))
        for g in grids:
            # one feature has one shape: a hand seen with two grid shapes gets a feature per shape
            key = raw_key(hand) if len(grids) == 1 else f"{raw_key(hand)}_{g[0]}x{g[1]}"
            slots.append(RawSlot(hand, g, key, key.removeprefix("observation.")))
    if int(reader.manifest.get("format_version", 0)) < 3:
        raise ArgumentError(f"{reader.root}: format {reader.manifest.get('format_version')} stores no raw glove rows; "
                            f"the export needs format 3 (re-ingest the sources)")
    if cfg.fps is not None:
        fps, resample = int(cfg.fps), True
    else:
        rates = {}
        for p in positions:
            ep = reader.episodes[p]
            rates.setdefault(int(round(float(ep.get("fps") or 0))), ep["episode_id"])
        if len(rates) != 1 or 0 in rates:
            raise ArgumentError(f"episodes have frame rates {sorted(rates)} (e.g. {sorted(rates.items())[:3]}); "
                                f"LeRobot has one fps per dataset: pass --fps F to resample")
        fps, resample = next(iter(rates)), False
    # a glove-only selection (no frame holds RGB) has no egocentric feature: no all-black video
    rgb = any(_has_rgb(reader, p) for p in positions)
    video_keys = ([RGB_KEY] if rgb else []) + ([map_key(h) for h in hands] if cfg.maps else [])
    return _Plan(positions, parts, hands, slots, layout_grids, layouts, fps, resample, split_doc, video_keys,
                 maps_gain=float(cfg.maps_gain), rgb=rgb)


def _has_rgb(reader: DatasetReader, pos: int) -> bool:
    """Whether any stored frame of episode `pos` holds an RGB member (from the index: no shard read)."""
    first, n = reader.episode_range(pos)
    return bool(np.any(reader.index[SIZE_FIELDS[RGB_MEMBER]][first:first + n] > 0))


def features(plan: _Plan) -> dict:
    """meta/info.json's feature table for `plan`: videos, raw glove rows (flat, the grid in "info"),
    observation.present, the source frame index and LeRobot's bookkeeping columns."""
    video_info = {"video.height": CANVAS, "video.width": CANVAS, "video.codec": "h264", "video.pix_fmt": "yuv420p",
                  "video.is_depth_map": False, "video.fps": plan.fps, "video.channels": 3, "has_audio": False}
    feats: dict = {}
    for key in plan.video_keys:
        feats[key] = {"dtype": "video", "shape": [CANVAS, CANVAS, 3], "names": ["height", "width", "channels"],
                      "info": dict(video_info)}
        if key != RGB_KEY:     # a map video: what its grey levels mean
            feats[key]["info"]["htdata.grey_level"] = f"round(clip(map value x {plan.maps_gain:g}, 0, 1) x 255)"
    for slot in plan.slots:
        rows, cols = slot.grid
        # flat (rows*cols,), row-major, the grid in "info": LeRobot's tooling and policies take state
        # features as 1-D vectors (lerobot-doctor 0.2.0 crashes on a 2-D one); reshape(rows, cols) restores it
        feats[slot.key] = {"dtype": "float32", "shape": [rows * cols],
                           "names": [f"r{r}c{c}" for r in range(rows) for c in range(cols)],
                           "info": {"grid": [rows, cols], "order": "row-major", "units": "raw glove units"}}
    feats[PRESENT_KEY] = {"dtype": "bool", "shape": [len(plan.present_names)], "names": plan.present_names}
    feats[SOURCE_KEY] = {"dtype": "int64", "shape": [1], "names": None,
                         "info": {"what": "the htdata frame (within its episode) this row was taken from"}}
    for name, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                        ("index", "int64"), ("task_index", "int64")):
        feats[name] = {"dtype": dtype, "shape": [1], "names": None}
    return feats


def _episode_schedule(reader: DatasetReader, pos: int, plan: _Plan) -> tuple[list[int], list[float]]:
    """(global sample index per exported frame, timestamp in s per exported frame) of one episode."""
    first, n = reader.episode_range(pos)
    eid = reader.episodes[pos]["episode_id"]
    times = []
    for i in range(first, first + n):
        meta = decode_member(JSON_MEMBER, reader.sample(i, (JSON_MEMBER,))[JSON_MEMBER], f"{reader.root}: {reader.key(i)}")
        if meta.get("t_rgb_ns") is None:
            raise DatasetError(f"{reader.root}: {reader.key(i)}: sample has no t_rgb_ns time")
        times.append(int(meta["t_rgb_ns"]))
    t = (np.asarray(times, np.int64) - times[0]) / 1e9
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise DatasetError(f"episode {eid!r} frame {k}: time does not increase ({t[k - 1]:.6f} s -> {t[k]:.6f} s)")
    ticks = np.arange(_ticks(t[-1], plan.fps)) / plan.fps
    right = np.clip(np.searchsorted(t, ticks), 0, n - 1)
    left = np.clip(right - 1, 0, n - 1)
    nearest = np.where(np.abs(t[left] - ticks) <= np.abs(t[right] - ticks), left, right)
    return [first + int(k) for k in nearest], ticks.tolist()


def _ticks(duration_s: float, fps: int) -> int:
    """Rows of an episode whose last frame is `duration_s` after its first: 1/fps ticks, the last one nearest it."""
    return int(round(duration_s * fps)) + 1


def _frames_out(reader: DatasetReader, pos: int, plan: _Plan) -> int:
    """Rows episode `pos` will have (two JSON reads)."""
    first, n = reader.episode_range(pos)
    t = [decode_member(JSON_MEMBER, reader.sample(i, (JSON_MEMBER,))[JSON_MEMBER], reader.key(i))["t_rgb_ns"]
         for i in (first, first + n - 1)]
    return _ticks((t[1] - t[0]) / 1e9, plan.fps)
