"""`htdata preview`: a contact sheet of one episode, drawn with cv2 only.

Rows are N frames in time order: by default the episode's phases
(`pick="phases"`: one frame before the first contact, frames spread over
the contact span, one after the last contact, so a reader sees the grasp
begin, hold and end; a part the episode lacks gives its rows to the contact
span), or the N frames with the most
contact (`pick="contact"`: hands in contact by each glove hand's contact
rule, htdata/glove/contact.py, then the highest taxel value; at least
len/(2N) frames apart; evenly spaced when nothing is in contact), or N
frames evenly spaced over the episode, first and last included
(`pick="even"`); columns are RGB | left tactile | right tactile (no RGB column for an
episode without video: a glove-only sheet is two columns wide). Each row is labelled with
its frame number and CLIP time (seconds since the episode's first frame). Tactile maps are
colour-mapped (inferno, 0 = black, 1 = pale yellow), the canonical region
outlines are drawn on top and named on the first row, pixels the glove does not
cover are shaded with a grey hatch (the legend under the sheet says so), and a
hand the episode does not have is a grey panel labelled
"no left hand" / "no right hand". Non-finite tactile pixels (a damaged
dataset) show as magenta rather than being hidden.

Contrast: "fixed" maps 0..1 onto the colour scale; "quantile" maps
0..vmax, vmax = the CONTRAST_QUANTILE of the dataset's positive taxel
values (from `htdata stats`, cached in DATASET/stats/), so faint contact
(0.02-0.45 after normalisation, common for raw-count gloves) becomes
visible; values above vmax saturate. "auto" (the default) is "quantile"
when that p99 is below AUTO_QUANTILE_BELOW (0.3), "fixed" otherwise. A
colour bar under the tactile columns shows the scale with its values
either way (its caption wrapped to the bar's width), and `htdata preview` prints its range.

Sheet size is fixed by the row count: see `sheet_size`.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from htdata.errors import ArgumentError
from htdata.format.canvas import CANVAS
from htdata.format.table import HANDS, JSON_MEMBER, RGB_MEMBER, SIZE_FIELDS, decode_member
from htdata.glove.canonical import PART_NAMES
from htdata.inspect.outline import region_outline
from htdata.inspect.stats import default_cache_dir, episode_stats, positive_value_quantile
from htdata.read.reader import DatasetReader

PAD = 8
TITLE_H = 30
HEADER_H = 22
COLUMNS = ("rgb", *HANDS)
COLUMN_TITLES = ("RGB", *(f"{hand} tactile" for hand in HANDS))
BACKGROUND = (32, 32, 32)        # BGR
ABSENT_GREY = (128, 128, 128)
OUTLINE = (255, 255, 255)
NONFINITE = (255, 0, 255)
TEXT = (235, 235, 235)
FONT = cv2.FONT_HERSHEY_SIMPLEX
BAR_STRIP_H = 14
BAR_FONT = 0.4
BAR_LINE_H = 14                  # caption line spacing
BAR_CAPTION_LINES = 3            # the caption (scale, frames, legend) wraps to at most this many lines
BAR_H = 56 + (BAR_CAPTION_LINES - 1) * BAR_LINE_H   # colour bar band under the rows (+ room for descenders)
BAR_TICKS = 5
CONTRASTS = ("auto", "fixed", "quantile")
PICKS = ("phases", "contact", "even")
PICK_WORDS = {"phases": "before / during / after contact", "contact": "most contact", "even": "evenly spaced"}
LEGEND = "hatched = no sensor, white lines = hand regions"
AUTO_QUANTILE_BELOW = 0.3        # contrast "auto": quantile when the dataset's p99 is below this
CONTRAST_QUANTILE = 0.99         # of the dataset's positive taxel values
MIN_VMAX = 0.01                  # never stretch further than this: noise would fill the panel


def sheet_columns(rgb: bool = True) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(columns, their titles): RGB and both hands, or only the hands for an episode without video."""
    return (COLUMNS, COLUMN_TITLES) if rgb else (COLUMNS[1:], COLUMN_TITLES[1:])


def sheet_size(rows: int, rgb: bool = True) -> tuple[int, int]:
    """(height, width) in pixels of a sheet with `rows` frames (`rgb` False: no RGB column)."""
    width = PAD + len(sheet_columns(rgb)[0]) * (CANVAS + PAD)
    height = TITLE_H + HEADER_H + rows * (CANVAS + PAD) + PAD + BAR_H
    return height, width


def frame_positions(num_frames: int, rows: int) -> np.ndarray:
    """`rows` evenly spaced frame numbers of an episode (all frames when it is shorter)."""
    if num_frames < 1:
        raise ValueError(f"an episode needs at least one frame, got {num_frames}")
    if rows < 1:
        raise ArgumentError(f"--frames must be >= 1, got {rows}")
    return np.unique(np.round(np.linspace(0, num_frames - 1, min(rows, num_frames))).astype(np.int64))


def hatch_mask(shape: tuple[int, int], spacing: int = 8) -> np.ndarray:
    yy, xx = np.indices(shape)
    return (xx + yy) % spacing == 0


def render_tactile(tmap: np.ndarray, coverage: np.ndarray, outline: np.ndarray, vmax: float = 1.0) -> np.ndarray:
    """(224,224) map in [0,1] -> (224,224,3) BGR panel (0..vmax on the colour scale), outlines, shaded uncovered area."""
    finite = np.isfinite(tmap)
    values = np.clip(np.where(finite, tmap, 0.0) / vmax, 0.0, 1.0)
    panel = cv2.applyColorMap(np.round(values * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
    uncovered = coverage == 0
    # shade, not hide: anything drawn outside coverage stays visible (dimmed)
    panel[uncovered] = (panel[uncovered] * 0.35 + 70).astype(np.uint8)
    panel[uncovered & hatch_mask(tmap.shape)] = (110, 110, 110)
    panel[outline] = OUTLINE
    panel[~finite] = NONFINITE
    return panel


def absent_panel(what: str) -> np.ndarray:
    """A grey panel saying what the sample does not hold ("no left hand", "no RGB (glove only)")."""
    panel = np.empty((CANVAS, CANVAS, 3), np.uint8)
    panel[:] = ABSENT_GREY
    text = f"no {what}"
    (tw, th), _ = cv2.getTextSize(text, FONT, 0.6, 1)
    cv2.putText(panel, text, ((CANVAS - tw) // 2, (CANVAS + th) // 2), FONT, 0.6, (255, 255, 255), 1,
                cv2.LINE_AA)
    return panel


def _label(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.45) -> None:
    # light text on a dark box stays readable on any panel
    (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
    x, y = org
    cv2.rectangle(img, (x - 2, y - th - 3), (x + tw + 2, y + base), (0, 0, 0), cv2.FILLED)
    cv2.putText(img, text, org, FONT, scale, TEXT, 1, cv2.LINE_AA)


def contrast_scale(dataset, contrast: str, version: int | None = None) -> tuple[str, float]:
    """(contrast used, top of the colour scale): "fixed" -> 1.0, "quantile" -> the dataset's
    CONTRAST_QUANTILE of positive taxel values, "auto" -> quantile when that is below AUTO_QUANTILE_BELOW."""
    if contrast not in CONTRASTS:
        raise ArgumentError(f"--contrast must be one of {', '.join(CONTRASTS)}, got {contrast!r}")
    if contrast == "fixed":
        return "fixed", 1.0
    try:
        q = positive_value_quantile(dataset, CONTRAST_QUANTILE, version=version)
    except (ValueError, KeyError):
        if contrast == "quantile":
            raise
        q = None       # auto on a dataset whose layouts the stats cannot sample: the fixed scale (said on the bar)
    vmax = float(min(1.0, max(MIN_VMAX, q))) if q else 1.0
    if contrast == "auto":
        return ("quantile", vmax) if q and q < AUTO_QUANTILE_BELOW else ("fixed", 1.0)
    return "quantile", vmax


def contrast_vmax(dataset, contrast: str, version: int | None = None) -> float:
    """Top of the colour scale of `contrast_scale`."""
    return contrast_scale(dataset, contrast, version)[1]


def contact_positions(stats: dict, num_frames: int, rows: int) -> np.ndarray:
    """The `rows` frames of an episode with the most contact, in time order (see the module docstring).

    `stats`: the episode's `htdata stats` entry (per hand: frame_index, frame_max, frame_contact).
    """
    hands = np.zeros(num_frames)
    peak = np.zeros(num_frames)
    for h in stats["hands"].values():
        idx = np.asarray(h["frame_index"], np.int64)
        if "frame_contact" in h:
            hands[idx] += np.asarray(h["frame_contact"], bool)
        peak[idx] += np.asarray(h["frame_max"], np.float64)
    if not hands.any():
        return frame_positions(num_frames, rows)
    gap = max(1, num_frames // (2 * max(rows, 1)))
    chosen: list[int] = []
    for f in np.lexsort((np.arange(num_frames), -peak, -hands)):      # most hands, then highest value
        if hands[f] == 0 or len(chosen) == rows:
            break
        if all(abs(int(f) - c) >= gap for c in chosen):
            chosen.append(int(f))
    # fewer frames in contact than rows: fill with evenly spaced frames, then any, so every row is drawn
    for f in [*frame_positions(num_frames, rows).tolist(), *range(num_frames)]:
        if len(chosen) >= min(rows, num_frames):
            break
        if f not in chosen:
            chosen.append(int(f))
    return np.asarray(sorted(chosen), np.int64)


def _contact_frames(stats: dict, num_frames: int) -> np.ndarray:
    """Per frame, how many hands are in contact (each hand's own contact rule, from `htdata stats`)."""
    hands = np.zeros(num_frames)
    for h in stats["hands"].values():
        if "frame_contact" in h:
            hands[np.asarray(h["frame_index"], np.int64)] += np.asarray(h["frame_contact"], bool)
    return hands


def phase_positions(stats: dict, num_frames: int, rows: int) -> np.ndarray:
    """`rows` frames showing the episode's phases, in time order (see the module docstring): the middle of
    the lead-in before the first contact, frames evenly over the contact span, the middle of the tail."""
    on = np.flatnonzero(_contact_frames(stats, num_frames))
    if not on.size or rows < 1:
        return frame_positions(num_frames, rows)
    first, last = int(on[0]), int(on[-1])
    edges = ([first // 2] if first > 0 and rows >= 3 else []) + \
            ([(last + 1 + num_frames - 1) // 2] if last < num_frames - 1 and rows >= 2 else [])
    during = max(1, rows - len(edges))
    # the middles of `during` equal slices of the contact span (one row: the middle of the hold, not its onset)
    span = on[np.unique(np.floor((np.arange(during) + 0.5) * on.size / during).astype(np.int64))]
    chosen = sorted({*map(int, span), *edges})
    for f in frame_positions(num_frames, rows).tolist():     # a short contact span: fill the rows evenly
        if len(chosen) >= min(rows, num_frames):
            break
        if f not in chosen:
            chosen = sorted({*chosen, int(f)})
    return np.asarray(chosen, np.int64)


def region_labels(parts: np.ndarray) -> list[tuple[str, tuple[int, int]]]:
    """(name, (x, y)) per hand region of the canonical part map: its name at the region pixel nearest the
    region's centroid (a curved finger's centroid can lie outside it)."""
    out = []
    for pid, name in PART_NAMES.items():
        ys, xs = np.nonzero(parts == pid)
        if not ys.size:
            continue
        k = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))
        out.append((name, (int(xs[k]), int(ys[k]))))
    return out


def wrap_text(text: str, width: int, scale: float = BAR_FONT, max_lines: int = BAR_CAPTION_LINES) -> list[str]:
    """`text` broken at spaces into lines no wider than `width` px (cv2's Hershey font at `scale`); a text
    longer than `max_lines` ends in "..." on the last line, so nothing is ever drawn past `width`."""
    def fits(line: str) -> bool:
        return cv2.getTextSize(line, FONT, scale, 1)[0][0] <= width

    lines: list[str] = []
    for word in text.split():
        if lines and fits(f"{lines[-1]} {word}"):
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    if len(lines) > max_lines:
        lines = lines[:max_lines]
        lines[-1] += " ..."
    for k, line in enumerate(lines):        # a single word wider than the bar is cut with "..."
        while not fits(line) and len(line) > 4:
            line = line[:-4] + "..."
        lines[k] = line
    return lines


def draw_colour_bar(sheet: np.ndarray, x: int, y: int, width: int, vmax: float, label: str) -> None:
    """Inferno strip 0..vmax at (x, y) with BAR_TICKS labelled ticks and a caption wrapped to `width`."""
    ramp = np.linspace(0, 255, width).astype(np.uint8)[None, :].repeat(BAR_STRIP_H, axis=0)
    sheet[y:y + BAR_STRIP_H, x:x + width] = cv2.applyColorMap(ramp, cv2.COLORMAP_INFERNO)
    for k in range(BAR_TICKS):
        tx = x + round(k * (width - 1) / (BAR_TICKS - 1))
        cv2.line(sheet, (tx, y + BAR_STRIP_H), (tx, y + BAR_STRIP_H + 4), TEXT, 1)
        text = f"{vmax * k / (BAR_TICKS - 1):.3g}" + ("+" if k == BAR_TICKS - 1 and vmax < 1.0 else "")
        (tw, _), _ = cv2.getTextSize(text, FONT, BAR_FONT, 1)
        cv2.putText(sheet, text, (min(max(tx - tw // 2, x), x + width - tw), y + BAR_STRIP_H + 17), FONT, BAR_FONT,
                    TEXT, 1, cv2.LINE_AA)
    for k, line in enumerate(wrap_text(label, width)):
        cv2.putText(sheet, line, (x, y + BAR_STRIP_H + 33 + k * BAR_LINE_H), FONT, BAR_FONT, TEXT, 1, cv2.LINE_AA)


def clip_time_s(reader: DatasetReader, first: int, i: int) -> float:
    """Seconds from the episode's first stored frame (sample `first`) to sample `i`, on the frames' own clock."""
    def t_ns(k: int) -> int:
        meta = decode_member(JSON_MEMBER, reader.sample(k, (JSON_MEMBER,))[JSON_MEMBER], reader.key(k))
        return int(meta["t_rgb_ns"])

    return (t_ns(i) - t_ns(first)) / 1e9


def episode_has_rgb(reader: DatasetReader, pos: int) -> bool:
    """Whether any frame of episode `pos` holds an RGB member (from the index, no shard read)."""
    first, n = reader.episode_range(pos)
    return bool(np.any(reader.index[SIZE_FIELDS[RGB_MEMBER]][first:first + n] > 0))


def _default_episode(episodes: list[dict]) -> str:
    def mean_contact(ep: dict) -> float:
        values = (ep.get("stats") or {}).get("mean_contact") or {}
        return min(values.values()) if values else 0.0   # min: every hand shows contact

    most = max(len(ep["hands"]) for ep in episodes)
    candidates = [ep for ep in episodes if len(ep["hands"]) == most]
    return max(candidates, key=mean_contact)["episode_id"]   # max() keeps the first on ties


def render_contact_sheet(dataset, episode: str | None = None, frames: int = 6, contrast: str = "auto",
                         pick: str = "phases") -> np.ndarray:
    """Contact sheet of one episode as a BGR uint8 image (contrast: "auto", "fixed" 0..1 or "quantile";
    pick: "phases", "contact" or "even" frames).

    Default episode: among those with the most hands (so a two-handed
    dataset shows both gloves and mirroring can be checked by eye), the one
    with the highest mean contact in its ingest stats (first on ties).
    """

    if pick not in PICKS:
        raise ArgumentError(f"--pick must be one of {', '.join(PICKS)}, got {pick!r}")
    contrast, vmax = contrast_scale(dataset, contrast)
    with DatasetReader(dataset) as reader:
        if not reader.episodes:
            raise ArgumentError(f"{dataset}: dataset has no episodes")
        if episode is None:
            episode = _default_episode(reader.episodes)
        try:
            pos = reader.episode_position(episode)
        except KeyError:
            known = ", ".join(ep["episode_id"] for ep in reader.episodes[:10])
            raise ArgumentError(f"{dataset}: no episode {episode!r} (first episodes: {known})") from None
        ep = reader.episodes[pos]
        first, n = reader.episode_range(pos)
        chosen = frame_positions(n, frames)
        picked = "evenly spaced"
        if pick != "even" and n:
            try:
                (entry,), _ = episode_stats(reader, [pos], cache_dir=default_cache_dir(reader.root))
                chosen = (phase_positions if pick == "phases" else contact_positions)(entry, n, frames)
                picked = PICK_WORDS[pick] if _contact_frames(entry, n).any() else "evenly spaced (no contact)"
            except (ValueError, KeyError):   # layouts the stats cannot sample: even spacing, said in the caption
                picked = "evenly spaced (no stats for this dataset)"
        outline = region_outline(reader.place_map)
        coverage = {hand: reader.coverage(layout_id) for hand, layout_id in ep["layouts"].items()}
        rgb = episode_has_rgb(reader, pos)
        sheet = _draw_rows(reader, ep, first, n, chosen, rgb, coverage, outline, vmax,
                           region_labels(reader.region_map))
        caption = ("tactile value, fixed scale 0..1" if contrast == "fixed" else
                   f"tactile value 0..{vmax:.3g} (p{CONTRAST_QUANTILE * 100:g} of the dataset's positive "
                   f"taxel values; above saturates)") + f"; frames: {picked}; {LEGEND}"
        x0 = PAD + (CANVAS + PAD if rgb else 0)          # under the tactile columns
        draw_colour_bar(sheet, x0, sheet.shape[0] - BAR_H + 4, 2 * CANVAS + PAD, vmax, caption)
    return sheet


def _draw_rows(reader: DatasetReader, ep: dict, first: int, n: int, chosen: np.ndarray, rgb: bool,
               coverage: dict, outline: np.ndarray, vmax: float, labels=()) -> np.ndarray:
    """The sheet without its colour bar: title, column heads, one row of panels per chosen frame."""
    _, titles = sheet_columns(rgb)
    height, width = sheet_size(len(chosen), rgb)
    sheet = np.empty((height, width, 3), np.uint8)
    sheet[:] = BACKGROUND
    title = (f"{ep['episode_id']}  task={ep['task']}  scene={ep['scene']}  {n} frames @ {ep['fps']:g} fps"
             + ("" if rgb else "  (glove only: no RGB)"))
    # a long id on a narrow (glove-only) sheet: a smaller font rather than text cut at the edge
    scale = min(0.5, 0.5 * (width - 2 * PAD - 4) / cv2.getTextSize(title, FONT, 0.5, 1)[0][0])
    _label(sheet, title, (PAD, 20), scale)
    for c, title in enumerate(titles):
        _label(sheet, title, (PAD + c * (CANVAS + PAD), TITLE_H + 15))
    for r, frame in enumerate(chosen):
        sample = reader.decoded(first + int(frame))
        y = TITLE_H + HEADER_H + r * (CANVAS + PAD)
        panels = []
        if rgb:
            panels.append(cv2.cvtColor(sample["rgb"], cv2.COLOR_RGB2BGR) if "rgb" in sample
                          else absent_panel("RGB (glove only)"))
        for hand in HANDS:
            if hand in sample["tactile"]:
                panel = render_tactile(sample["tactile"][hand], coverage[hand], outline, vmax)
                for name, (px, py) in (labels if r == 0 else ()):   # region names once, on the first row
                    (tw, th), _ = cv2.getTextSize(name, FONT, 0.35, 1)
                    _label(panel, name, (max(0, min(CANVAS - tw, px - tw // 2)), max(th, py + th // 2)), 0.35)
                panels.append(panel)
            else:   # an RGB-only sample (format 3) or a hand the episode does not have
                panels.append(absent_panel("tactile" if sample["meta"].get("rgb_only") and hand in ep["hands"]
                                           else f"{hand} hand"))
        for c, panel in enumerate(panels):
            x = PAD + c * (CANVAS + PAD)
            sheet[y:y + CANVAS, x:x + CANVAS] = panel
        _label(sheet, f"frame {int(frame)}  t={clip_time_s(reader, first, first + int(frame)):.3f}s", (PAD + 4, y + 16))
    return sheet


def write_preview(dataset, out, episode: str | None = None, frames: int = 6, contrast: str = "auto",
                  pick: str = "phases") -> Path:
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ArgumentError(f"{out}: the preview is written as PNG; give a .png path")
    sheet = render_contact_sheet(dataset, episode=episode, frames=frames, contrast=contrast, pick=pick)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), sheet):
        raise OSError(f"{out}: cv2 could not write the PNG")
    return out
