"""What `htdata view` shows of one episode, before a sample is read: entities, static layers, blueprint.

`ViewPlan` is the episode chosen and what it holds (from the index and the
records only): its hands, whether it has video, which hands have bend values
and raw-count glove rows (a layout whose full scale `value.max` is above 1:
counts, not values already in [0,1]), and the colour scale of the maps
(`preview.contrast_scale`). The entity paths are fixed here (ENTITY_* below),
so the logger, the blueprint and the tests spell them once:

    rgb                       the stored JPEG, as an encoded image
    tactile/<hand>/map        the 224x224 map (float32), inferno over 0..vmax like `htdata preview`
    tactile/<hand>/no_sensor  static overlay: where the glove has no sensor, dimmed and hatched as in
                              `preview`, with the canonical region outlines
    raw/<hand>                the raw glove grid paired with each frame (raw-count gloves), source dtype
    regions/<hand>            mean map value per hand part (thumb .. palm) over the covered pixels
    bend/<hand>               the bend (flex) values, where the glove has them
    skew/<hand>               RGB minus tactile time of each frame, in ms, where the dataset recorded it
    episode                   static: the episode's id, task, scene, layouts and colour scale

The blueprint puts RGB beside the two hands (a hand the episode lacks has no
view, a glove-only episode no RGB view), the raw grids under them when there
are any, and the curves below (with the episode's note). Nothing here imports rerun: the caller passes
the module in (`rr`, `rrb`), so htdata imports without the `view` extra.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from htdata.format.table import HANDS, RGB_MEMBER, SIZE_FIELDS, bend_member, raw_member
from htdata.glove.canonical import PART_NAMES
from htdata.glove.glovevalue import full_scale, is_raw_count
from htdata.inspect.outline import region_outline
from htdata.inspect.preview import hatch_mask

ENTITY_RGB = "rgb"
ENTITY_EPISODE = "episode"
TIMELINE_FRAME = "frame"         # the frame within the episode (0..n-1)
TIMELINE_TIME = "time"           # seconds since the episode's first frame, on the frames' own clock
MAP_DTYPE = np.float32           # what a map is logged as: the values served, exactly (float16 would halve the
                                 # bytes but its conversion costs more CPU than decoding the map did)
UNCOVERED_ALPHA = 0.65           # preview dims uncovered pixels to 0.35 x colour + 70: grey 108 at this alpha
UNCOVERED_GREY = 108
HATCH_GREY = 110
OUTLINE_WHITE = 255


def map_entity(hand: str) -> str:
    return f"tactile/{hand}/map"


def overlay_entity(hand: str) -> str:
    return f"tactile/{hand}/no_sensor"


def raw_entity(hand: str) -> str:
    return f"raw/{hand}"


def regions_entity(hand: str) -> str:
    return f"regions/{hand}"


def bend_entity(hand: str) -> str:
    return f"bend/{hand}"


def skew_entity(hand: str) -> str:
    return f"skew/{hand}"


@dataclass
class ViewPlan:
    """One episode as the view will show it (see the module docstring)."""
    dataset: str
    version: int
    position: int                    # in episodes.jsonl
    episode: dict                    # its record
    first: int                       # global index of its first sample
    num_frames: int
    rgb: bool                        # any frame holds an RGB member
    contrast: str                    # "fixed" or "quantile" (auto resolved)
    vmax: float                      # top of the maps' colour scale
    hands: tuple[str, ...] = ()      # the episode's hands, in HANDS order
    raw_hands: tuple[str, ...] = ()  # hands with a raw-count glove grid stored
    bend_hands: tuple[str, ...] = ()
    raw_max: dict = field(default_factory=dict)   # hand -> the layout's full scale (the raw view's range)

    @property
    def episode_id(self) -> str:
        return self.episode["episode_id"]


def plan_episode(reader, pos: int, contrast: str, vmax: float) -> ViewPlan:
    """What episode `pos` of `reader`'s version holds, from its index rows and records (no shard read)."""
    ep = reader.episodes[pos]
    first, n = reader.episode_range(pos)
    rows = reader.index[first:first + n]

    def stored(suffix: str) -> bool:
        column = SIZE_FIELDS.get(suffix)
        return column is not None and column in rows.dtype.names and bool(np.any(rows[column] > 0))

    hands = tuple(h for h in HANDS if h in ep["layouts"])
    raw_max = {}
    for hand in hands:
        top = full_scale(reader.layout(ep["layouts"][hand]).get("value"))
        if is_raw_count(top) and stored(raw_member(hand)):
            raw_max[hand] = top
    return ViewPlan(dataset=str(reader.root), version=int(reader.version), position=pos, episode=ep, first=first,
                    num_frames=n, rgb=stored(RGB_MEMBER), contrast=contrast, vmax=vmax, hands=hands,
                    raw_hands=tuple(raw_max), bend_hands=tuple(h for h in hands if stored(bend_member(h))),
                    raw_max=raw_max)


def sensor_overlay(coverage: np.ndarray, place_map: np.ndarray) -> np.ndarray:
    """(224,224,4) RGBA drawn over a map: `preview`'s shading of where the glove has no sensor (dimmed,
    grey hatch) and the region outlines in white; transparent elsewhere."""
    uncovered = np.asarray(coverage) == 0
    out = np.zeros((*uncovered.shape, 4), np.uint8)
    out[uncovered] = (UNCOVERED_GREY, UNCOVERED_GREY, UNCOVERED_GREY, round(255 * UNCOVERED_ALPHA))
    out[uncovered & hatch_mask(uncovered.shape)] = (HATCH_GREY, HATCH_GREY, HATCH_GREY, 255)
    out[region_outline(place_map)] = (OUTLINE_WHITE, OUTLINE_WHITE, OUTLINE_WHITE, 255)
    return out


@dataclass(frozen=True)
class RegionMeans:
    """Mean map value per hand part over the pixels a glove covers: the parts' names and ids, and each
    pixel's part (0: not counted) so one weighted bincount (float64 sums) gives every mean of a map."""
    names: tuple[str, ...]
    parts: np.ndarray        # (k,) part ids, in names' order
    counts: np.ndarray       # (k,) covered pixels of each
    labels: np.ndarray       # (224*224,) intp: the pixel's part id where covered, else 0

    @classmethod
    def of(cls, part_map: np.ndarray, coverage: np.ndarray) -> "RegionMeans":
        """The parts (thumb=1 .. palm=6 in `part_map`) the glove covers at least one pixel of."""
        labels = np.where(np.asarray(coverage).ravel() > 0, np.asarray(part_map).ravel(), 0).astype(np.intp)
        counts = np.bincount(labels, minlength=max(PART_NAMES) + 1)
        parts = [p for p in PART_NAMES if counts[p] > 0]
        return cls(tuple(PART_NAMES[p] for p in parts), np.asarray(parts, np.intp),
                   counts[parts].astype(np.float64), labels)

    def __call__(self, tmap: np.ndarray) -> np.ndarray:
        """(224,224) map -> (k,) float64 means."""
        sums = np.bincount(self.labels, weights=np.asarray(tmap).ravel(), minlength=max(PART_NAMES) + 1)
        return sums[self.parts] / self.counts


def blueprint(rrb, plan: ViewPlan):
    """The layout of the viewer: RGB beside the hands, raw grids under them (if any), curves below."""
    top = [rrb.Spatial2DView(origin=ENTITY_RGB, name="RGB")] if plan.rgb else []
    top += [rrb.Spatial2DView(origin=f"tactile/{h}", name=f"{h} tactile") for h in plan.hands]
    rows = [rrb.Horizontal(*top)]
    if plan.raw_hands:
        rows.append(rrb.Horizontal(*[rrb.TensorView(origin=raw_entity(h), name=f"{h} raw glove grid")
                                     for h in plan.raw_hands]))
    curves = [rrb.TimeSeriesView(origin=regions_entity(h), name=f"{h}: mean value per region") for h in plan.hands]
    curves += [rrb.TimeSeriesView(origin=bend_entity(h), name=f"{h}: bend") for h in plan.bend_hands]
    if plan.rgb and plan.hands:
        curves.append(rrb.TimeSeriesView(origin="skew", name="RGB - tactile skew (ms)"))
    rows.append(rrb.Horizontal(*curves, rrb.TextDocumentView(origin=ENTITY_EPISODE, name="episode")))
    return rrb.Blueprint(rrb.Vertical(*rows, row_shares=[3, 2, 2] if plan.raw_hands else [3, 2]),
                         collapse_panels=True)


def episode_text(plan: ViewPlan) -> str:
    """The static note beside the views: what the episode is and how its maps are coloured."""
    ep = plan.episode
    scale = ("fixed 0..1" if plan.contrast == "fixed" else
             f"0..{plan.vmax:.3g} (p99 of the dataset's positive taxel values; above saturates)")
    lines = [f"# {plan.episode_id}", "",
             f"task {ep.get('task')}, scene {ep.get('scene')}; {plan.num_frames} frames at {ep.get('fps', 0):g} fps; "
             f"dataset {plan.dataset} version {plan.version}", "",
             "Gloves: " + (", ".join(f"{h} {ep['layouts'][h]}" for h in plan.hands) or "none")
             + ("" if plan.rgb else " (glove only: no RGB)"), "",
             f"Map colours: inferno, {scale}. Dimmed and hatched: no sensor there. White: region outlines."]
    return "\n".join(lines)
