"""`htdata view`: one episode in Rerun, streamed frame by frame: RGB, both hands' maps and their curves.

`view_episode` opens a version, chooses the episode (default: the first, of
the split part when one is given; an unknown id is the did-you-mean line of
htdata/store/episodeids.py), and logs it on two timelines that index the same
rows: `frame` (0..n-1) and `time` (seconds since the episode's first frame,
from its stored timestamps `t_rgb_ns`). What is logged where, and the
blueprint, are htdata/inspect/viewlayout.py's. The RGB is the stored JPEG
logged as an encoded image (never decoded and re-encoded); each map is logged
as its float32 values, coloured by the viewer (inferno over the `preview`
colour scale), so the values stay readable (hover) and equal, bit for bit,
what `htdata.open(...).decoded(i)` serves.

Memory stays bounded by BATCH frames: samples are read one at a time and
sent to Rerun in columns of BATCH rows (one call per entity and batch, far
cheaper than one per frame), and the Rerun sink streams them to the file or
the viewer. `--save` writes FILE.rrd.tmp and renames it once the recording is
complete: an error (a damaged sample, a full disk) leaves no .rrd behind.

rerun-sdk is an optional extra (`pip install '.[view]'`): `load_rerun` imports
it and turns its absence into one line naming the extra.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, HtdataError
from htdata.format.canvas import CANVAS
from htdata.format.table import JSON_MEMBER, RGB_MEMBER, bend_member, raw_member, tactile_member
from htdata.inspect.preview import contrast_scale
from htdata.inspect.viewlayout import (
    ENTITY_EPISODE,
    ENTITY_RGB,
    MAP_DTYPE,
    TIMELINE_FRAME,
    TIMELINE_TIME,
    RegionMeans,
    ViewPlan,
    bend_entity,
    blueprint,
    episode_text,
    map_entity,
    overlay_entity,
    plan_episode,
    raw_entity,
    regions_entity,
    sensor_overlay,
    skew_entity,
)
from htdata.read.reader import DatasetReader
from htdata.store.episodeids import no_such_episode

VIEW_EXTRA = "pip install '.[view]'"
BATCH = 32                     # frames per column batch sent to Rerun (the memory bound, in frames)
APPLICATION_ID = "htdata"
WEB_PORT = 9090                # the web viewer's page (Rerun's default port)
GRPC_PORT = 9876               # the data the web page reads (Rerun's default gRPC port)
MAP_DRAW_ORDER = 0.0           # the no-sensor overlay is drawn just above its map


class ViewerMissing(HtdataError, ImportError):
    """rerun-sdk is not installed: one line naming the extra that brings it."""


class ViewerFailed(HtdataError, RuntimeError):
    """The native viewer could not be started (none found, no display): one line naming the alternatives."""


def load_rerun():
    """(rerun, rerun.blueprint), or ViewerMissing naming `pip install '.[view]'`."""
    try:
        import rerun
        import rerun.blueprint
    except ImportError as exc:
        raise ViewerMissing(f"rerun-sdk is not installed ({exc.name} does not import): {VIEW_EXTRA}") from None
    return rerun, rerun.blueprint


def choose_episode(reader: DatasetReader, episode: str | None, split: str | None = None,
                   part: str | None = None) -> int:
    """Position of the episode to show: `episode` (an id), else the first of the version or of split/part.

    Raises:
        NoSuchEpisode: an id the version (or the split part) does not have, with its near matches.
        ArgumentError: an empty version or split part; a part without a split or a split without a part.
    """
    positions = reader.meta.episode_positions(split, part)
    where = f"{reader.root} version {reader.version}" + (f", split {split!r} part {part!r}" if split else "")
    if not positions:
        raise ArgumentError(f"{where}: no episodes to view")
    ids = [reader.episodes[p]["episode_id"] for p in positions]
    if episode is None:
        return positions[0]
    if episode not in ids:
        raise no_such_episode(episode, ids, "episodes" if split is None else f"episodes in {split}/{part}")
    return positions[ids.index(episode)]


@dataclass
class ViewResult:
    plan: ViewPlan
    target: str          # the .rrd written, the web viewer's URL, or "viewer" (spawned)
    frames: int          # samples logged
    # --web: the stream whose gRPC server the page reads. Rerun serves only while this object lives,
    # so the caller keeps it until it stops serving (dropping it closes the data port).
    stream: object = None
    data_url: str = ""   # --web: the gRPC address of that server (what `rerun URL` connects to)


class _Columns:
    """Rows waiting to be sent, per entity: frame, time and value; `send` empties them into Rerun."""

    def __init__(self):
        self.rows: dict[str, tuple[list, list, list]] = {}

    def add(self, entity: str, frame: int, t_ns: int, value) -> None:
        frames, times, values = self.rows.setdefault(entity, ([], [], []))
        frames.append(frame)
        times.append(t_ns)
        values.append(value)

    def send(self, rec, rr) -> None:
        for entity, (frames, times, values) in self.rows.items():
            index = [rr.TimeColumn(TIMELINE_FRAME, sequence=frames),
                     rr.TimeColumn(TIMELINE_TIME, duration=np.asarray(times, "timedelta64[ns]"))]
            if entity == ENTITY_RGB:
                columns = rr.EncodedImage.columns(blob=values)
            elif entity.startswith("tactile/"):   # each map's bytes (the static format says how to read them)
                columns = rr.DepthImage.columns(buffer=values)
            else:
                columns = rr.Scalars.columns(scalars=np.concatenate(values)).partition([len(v) for v in values])
            rec.send_columns(entity, index, columns)
        self.rows.clear()


def log_static(rec, rr, reader: DatasetReader, plan: ViewPlan) -> dict[str, RegionMeans]:
    """The rows every frame shares: formats, colour scales, overlays, series names, the episode note."""
    rec.log(ENTITY_EPISODE, rr.TextDocument(episode_text(plan), media_type=rr.MediaType.MARKDOWN), static=True)
    if plan.rgb:
        rec.log(ENTITY_RGB, rr.EncodedImage.from_fields(media_type="image/jpeg"), static=True)
    regions = {}
    for hand in plan.hands:
        coverage = reader.coverage(plan.episode["layouts"][hand])
        rec.log(map_entity(hand), rr.DepthImage.from_fields(
            format=rr.components.ImageFormat(CANVAS, CANVAS, channel_datatype="F32"), meter=1.0,
            colormap="inferno", depth_range=(0.0, plan.vmax), draw_order=MAP_DRAW_ORDER), static=True)
        rec.log(overlay_entity(hand), rr.Image(sensor_overlay(coverage, reader.place_map), color_model="RGBA",
                                               draw_order=MAP_DRAW_ORDER + 1), static=True)
        regions[hand] = RegionMeans.of(reader.region_map, coverage)
        rec.log(regions_entity(hand), rr.SeriesLines(names=list(regions[hand].names)), static=True)
        if hand in plan.bend_hands:
            cells = reader.layout(plan.episode["layouts"][hand]).get("bend_cells") or []
            if cells:   # named by the grid cell each value is read from
                rec.log(bend_entity(hand), rr.SeriesLines(names=[f"bend ({r},{c})" for r, c in cells]), static=True)
        if plan.rgb:
            rec.log(skew_entity(hand), rr.SeriesLines(names=[hand]), static=True)
        if hand in plan.raw_hands:
            rec.log(raw_entity(hand), rr.Tensor.from_fields(value_range=(0.0, plan.raw_max[hand])), static=True)
    return regions


def _members(plan: ViewPlan) -> tuple[str, ...]:
    """The members decoded per sample (the JPEG is read as bytes apart)."""
    wanted = [JSON_MEMBER, *(tactile_member(h) for h in plan.hands)]
    return (*wanted, *(bend_member(h) for h in plan.bend_hands), *(raw_member(h) for h in plan.raw_hands))


def log_episode(rec, rr, reader: DatasetReader, plan: ViewPlan, batch: int = BATCH) -> int:
    """Stream the episode's samples into `rec` (see the module docstring); returns the samples logged.

    Raises:
        DatasetError: a sample that does not decode (a non-finite map, a damaged member), named.
    """
    regions = log_static(rec, rr, reader, plan)
    members = _members(plan)
    pending = _Columns()
    t0 = None
    for frame in range(plan.num_frames):
        i = plan.first + frame
        sample = reader.decoded(i, members)
        meta = sample["meta"]
        t0 = int(meta["t_rgb_ns"]) if t0 is None else t0
        t_ns = int(meta["t_rgb_ns"]) - t0
        if plan.rgb:
            jpeg = reader.sample(i, (RGB_MEMBER,)).get(RGB_MEMBER)
            if jpeg:
                pending.add(ENTITY_RGB, frame, t_ns, jpeg)
        for hand in plan.hands:
            _log_hand(rec, rr, pending, plan, hand, sample, frame, t_ns, regions[hand])
        if (frame + 1) % batch == 0:
            pending.send(rec, rr)
    pending.send(rec, rr)
    rec.reset_time()
    return plan.num_frames


def _log_hand(rec, rr, pending: _Columns, plan: ViewPlan, hand: str, sample: dict, frame: int, t_ns: int,
              regions: RegionMeans) -> None:
    """One hand of one sample: its map, region means, bend and skew (batched), its raw grid (logged now)."""
    meta = sample["meta"]
    paired = (meta.get("raw_paired") or {}).get(hand)
    rows = sample["raw"].get(hand)
    if hand in plan.raw_hands and rows is not None and paired is not None:
        _at(rec, rr, frame, t_ns)
        rec.log(raw_entity(hand), rr.Tensor(rows[int(paired)], dim_names=["row", "col"]))
    tmap = sample["tactile"].get(hand)
    if tmap is None:   # an RGB-only frame: no map shown at it (not the previous one), the curves break
        _at(rec, rr, frame, t_ns)
        rec.log(map_entity(hand), rr.Clear(recursive=False))
        pending.add(regions_entity(hand), frame, t_ns, np.full(len(regions.names), np.nan))
        return
    # as bytes: the SDK's fast path (an array of maps it copies three times; bytes once)
    pending.add(map_entity(hand), frame, t_ns, np.asarray(tmap, MAP_DTYPE).tobytes())
    pending.add(regions_entity(hand), frame, t_ns, regions(tmap))
    if hand in sample["bend"]:
        pending.add(bend_entity(hand), frame, t_ns, np.asarray(sample["bend"][hand], np.float64))
    if plan.rgb and not meta.get("tactile_only") and hand in (meta.get("sync_offset_ns") or {}):
        pending.add(skew_entity(hand), frame, t_ns, np.array([meta["sync_offset_ns"][hand] / 1e6]))


def _at(rec, rr, frame: int, t_ns: int) -> None:
    rec.set_time(TIMELINE_FRAME, sequence=frame)
    rec.set_time(TIMELINE_TIME, duration=np.timedelta64(t_ns, "ns"))


def view_episode(dataset, *, episode: str | None = None, version: int | None = None, split: str | None = None,
                 part: str | None = None, contrast: str = "auto", save=None, web: bool = False,
                 open_browser: bool = True, web_port: int = WEB_PORT, grpc_port: int = GRPC_PORT) -> ViewResult:
    """Log one episode to Rerun: into `save` (an .rrd file, nothing opened), a served web viewer (`web`),
    or a spawned native viewer (neither). With `web`, the returned `stream` must be kept alive for as
    long as the viewer is to be served (the data port closes when it is dropped).

    Raises:
        ViewerMissing: rerun-sdk is not installed.
        ArgumentError: a bad episode / split / part / version / contrast, or `save` not ending in .rrd.
        DatasetError: a sample that does not decode.
    """
    if save is not None and Path(save).suffix.lower() != ".rrd":
        raise ArgumentError(f"{save}: a Rerun recording is written as .rrd; give a .rrd path")
    if save is not None and web:
        raise ArgumentError("--save writes a file and opens nothing; --web serves a viewer: give one of them")
    rr, rrb = load_rerun()
    used, vmax = contrast_scale(dataset, contrast, version)
    with DatasetReader(dataset, version=version) as reader:
        plan = plan_episode(reader, choose_episode(reader, episode, split, part), used, vmax)
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"{plan.episode_id}@v{plan.version}")
        rec.set_log_tick_enabled(False)   # one timeline pair, frame and time; not the SDK's own clocks
        rec.set_log_time_enabled(False)
        layout = blueprint(rrb, plan)
        if save is not None:
            return ViewResult(plan, str(_save(rec, rr, reader, plan, Path(save), layout)), plan.num_frames)
        if web:
            try:
                grpc = rec.serve_grpc(grpc_port=grpc_port, default_blueprint=layout)
                rr.serve_web_viewer(web_port=web_port, connect_to=grpc, open_browser=open_browser)
            except RuntimeError as exc:   # a port in use, most often
                raise ViewerFailed(f"the web viewer could not be served ({_first_line(exc)}); write the recording "
                                   "with --save FILE.rrd instead") from None
            target = f"http://localhost:{web_port}/?url={grpc}"
        else:
            _spawn(rr, rec, layout)
            target = "viewer"
        try:
            rec.send_recording_name(plan.episode_id)
            frames = log_episode(rec, rr, reader, plan)
            rec.flush()
        except RuntimeError as exc:   # the viewer went away mid-stream (closed, crashed)
            raise ViewerFailed(f"the Rerun viewer stopped taking data ({_first_line(exc)}); write the recording "
                               "with --save FILE.rrd instead") from None
        if web:
            return ViewResult(plan, target, frames, stream=rec, data_url=grpc)
        return ViewResult(plan, target, frames)


def _spawn(rr, rec, layout) -> None:
    """Start the native viewer: the `rerun` beside this interpreter (a venv not on PATH), else PATH's."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerFailed("no display to open the Rerun viewer on (DISPLAY and WAYLAND_DISPLAY are unset); write "
                           "the recording with --save FILE.rrd, or serve it to a browser with --web")
    beside = Path(sys.executable).with_name("rerun")
    try:
        rr.spawn(recording=rec, default_blueprint=layout, executable_path=str(beside) if beside.is_file() else None)
    except RuntimeError as exc:
        raise ViewerFailed(f"the Rerun viewer did not start ({_first_line(exc)}); write the recording with --save "
                           "FILE.rrd, or serve it to a browser with --web") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _save(rec, rr, reader: DatasetReader, plan: ViewPlan, out: Path, layout) -> Path:
    """Write the recording to OUT.tmp, complete, then rename it to OUT (an error leaves neither)."""
    tmp = out.with_name(out.name + ".tmp")
    try:
        rec.save(tmp, default_blueprint=layout)
        rec.send_recording_name(plan.episode_id)
        log_episode(rec, rr, reader, plan)
        rec.flush()
        rec.disconnect()
        os.replace(tmp, out)
    except BaseException:
        rec.disconnect()
        tmp.unlink(missing_ok=True)
        raise
    return out
