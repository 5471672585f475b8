"""`htdata preview`: a contact sheet of one episode, drawn with cv2 only.

Rows are N frames in time order: by default the N frames with the most
contact (`pick="contact"`: hands in contact by each glove hand's contact
rule, htdata/glove/contact.py, then the highest taxel value; at least
len/(2N) frames apart; evenly spaced when nothing is in contact), or N
frames evenly spaced over the episode, first and last included
(`pick="even"`); columns are RGB | left tactile | right tactile. Tactile maps are
colour-mapped (inferno, 0 = black, 1 = pale yellow), the canonical region
outlines are drawn on top, pixels the glove does not cover are shaded with a
grey hatch, and a hand the episode does not have is a grey panel labelled
"no left hand" / "no right hand". Non-finite tactile pixels (a damaged
dataset) show as magenta rather than being hidden.

Contrast: "fixed" maps 0..1 onto the colour scale; "quantile" maps
0..vmax, vmax = the CONTRAST_QUANTILE of the dataset's positive taxel
values (from `htdata stats`, cached in DATASET/stats/), so faint contact
(0.02-0.45 after normalisation, common for raw-count gloves) becomes
visible; values above vmax saturate. "auto" (the default) is "quantile"
when that p99 is below AUTO_QUANTILE_BELOW (0.3), "fixed" otherwise. A
colour bar under the tactile columns shows the scale with its values
either way, and `htdata preview` prints its range.

Sheet size is fixed by the row count: see `sheet_size`.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from htdata.format.table import CANVAS, HANDS
from htdata.inspect.outline import region_outline  # noqa: F401  (preview.region_outline stays a name of this module)
from htdata.inspect.stats import positive_value_quantile
from htdata.read.reader import DatasetReader
from htdata.inspect.stats import default_cache_dir, episode_stats

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
BAR_H = 52                       # colour bar band under the rows
BAR_STRIP_H = 14
BAR_TICKS = 5
CONTRASTS = ("auto", "fixed", "quantile")
PICKS = ("contact", "even")
AUTO_QUANTILE_BELOW = 0.3        # contrast "auto": quantile when the dataset's p99 is below this
CONTRAST_QUANTILE = 0.99         # of the dataset's positive taxel values
MIN_VMAX = 0.01                  # never stretch further than this: noise would fill the panel


def sheet_size(rows: int) -> tuple[int, int]:
    """(height, width) in pixels of a sheet with `rows` frames."""
    width = PAD + len(COLUMNS) * (CANVAS + PAD)
    height = TITLE_H + HEADER_H + rows * (CANVAS + PAD) + PAD + BAR_H
    return height, width


def frame_positions(num_frames: int, rows: int) -> np.ndarray:
    """`rows` evenly spaced frame numbers of an episode (all frames when it is shorter)."""
    if num_frames < 1:
        raise ValueError(f"an episode needs at least one frame, got {num_frames}")
    if rows < 1:
        raise ValueError(f"--frames must be >= 1, got {rows}")
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
        raise ValueError(f"--contrast must be one of {', '.join(CONTRASTS)}, got {contrast!r}")
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


def draw_colour_bar(sheet: np.ndarray, x: int, y: int, width: int, vmax: float, label: str) -> None:
    """Inferno strip 0..vmax at (x, y) with BAR_TICKS labelled ticks and a caption."""
    ramp = np.linspace(0, 255, width).astype(np.uint8)[None, :].repeat(BAR_STRIP_H, axis=0)
    sheet[y:y + BAR_STRIP_H, x:x + width] = cv2.applyColorMap(ramp, cv2.COLORMAP_INFERNO)
    for k in range(BAR_TICKS):
        tx = x + round(k * (width - 1) / (BAR_TICKS - 1))
        cv2.line(sheet, (tx, y + BAR_STRIP_H), (tx, y + BAR_STRIP_H + 4), TEXT, 1)
        text = f"{vmax * k / (BAR_TICKS - 1):.3g}" + ("+" if k == BAR_TICKS - 1 and vmax < 1.0 else "")
        (tw, _), _ = cv2.getTextSize(text, FONT, 0.4, 1)
        cv2.putText(sheet, text, (min(max(tx - tw // 2, x), x + width - tw), y + BAR_STRIP_H + 17), FONT, 0.4,
                    TEXT, 1, cv2.LINE_AA)
    cv2.putText(sheet, label, (x, y + BAR_STRIP_H + 33), FONT, 0.4, TEXT, 1, cv2.LINE_AA)


def _default_episode(episodes: list[dict]) -> str:
    def mean_contact(ep: dict) -> float:
        values = (ep.get("stats") or {}).get("mean_contact") or {}
        return min(values.values()) if values else 0.0   # min: every hand shows contact

    most = max(len(ep["hands"]) for ep in episodes)
    candidates = [ep for ep in episodes if len(ep["hands"]) == most]
    return max(candidates, key=mean_contact)["episode_id"]   # max() keeps the first on ties


def render_contact_sheet(dataset, episode: str | None = None, frames: int = 6, contrast: str = "auto",
                         pick: str = "contact") -> np.ndarray:
    """Contact sheet of one episode as a BGR uint8 image (contrast: "auto", "fixed" 0..1 or "quantile";
    pick: "contact" or "even" frames).

    Default episode: among those with the most hands (so a two-handed
    dataset shows both gloves and mirroring can be checked by eye), the one
    with the highest mean contact in its ingest stats (first on ties).
    """

    if pick not in PICKS:
        raise ValueError(f"--pick must be one of {', '.join(PICKS)}, got {pick!r}")
    contrast, vmax = contrast_scale(dataset, contrast)
    with DatasetReader(dataset) as reader:
        if not reader.episodes:
            raise ValueError(f"{dataset}: dataset has no episodes")
        if episode is None:
            episode = _default_episode(reader.episodes)
        try:
            pos = reader.episode_position(episode)
        except KeyError:
            known = ", ".join(ep["episode_id"] for ep in reader.episodes[:10])
            raise ValueError(f"{dataset}: no episode {episode!r} (first episodes: {known})") from None
        ep = reader.episodes[pos]
        first, n = reader.episode_range(pos)
        chosen = frame_positions(n, frames)
        picked = "evenly spaced"
        if pick == "contact" and n:
            try:
                (entry,), _ = episode_stats(reader, [pos], cache_dir=default_cache_dir(reader.root))
                chosen = contact_positions(entry, n, frames)
                picked = "most contact"
            except (ValueError, KeyError):   # layouts the stats cannot sample: even spacing, said in the caption
                picked = "evenly spaced (no stats for this dataset)"
        outline = region_outline(reader.place_map)
        coverage = {hand: reader.coverage(layout_id) for hand, layout_id in ep["layouts"].items()}

        height, width = sheet_size(len(chosen))
        sheet = np.empty((height, width, 3), np.uint8)
        sheet[:] = BACKGROUND
        _label(sheet, f"{ep['episode_id']}  task={ep['task']}  scene={ep['scene']}  "
                      f"{n} frames @ {ep['fps']:g} fps", (PAD, 20), 0.5)
        for c, title in enumerate(COLUMN_TITLES):
            _label(sheet, title, (PAD + c * (CANVAS + PAD), TITLE_H + 15))
        t0 = None
        for r, frame in enumerate(chosen):
            sample = reader.decoded(first + int(frame))
            y = TITLE_H + HEADER_H + r * (CANVAS + PAD)
            panels = [cv2.cvtColor(sample["rgb"], cv2.COLOR_RGB2BGR) if "rgb" in sample
                      else absent_panel("RGB (glove only)")]
            for hand in HANDS:
                if hand in sample["tactile"]:
                    panels.append(render_tactile(sample["tactile"][hand], coverage[hand], outline, vmax))
                else:   # an RGB-only sample (format 3) or a hand the episode does not have
                    panels.append(absent_panel("tactile" if sample["meta"].get("rgb_only") and hand in ep["hands"]
                                              else f"{hand} hand"))
            for c, panel in enumerate(panels):
                x = PAD + c * (CANVAS + PAD)
                sheet[y:y + CANVAS, x:x + CANVAS] = panel
            t = sample["meta"]["t_rgb_ns"]
            t0 = t if t0 is None else t0
            _label(sheet, f"frame {int(frame)}  t={(t - t0) / 1e9:.3f}s", (PAD + 4, y + 16))
        caption = ("tactile value, fixed scale 0..1" if contrast == "fixed" else
                   f"tactile value 0..{vmax:.3g} (p{CONTRAST_QUANTILE * 100:g} of the dataset's positive "
                   f"taxel values; above saturates)") + f"; frames: {picked}"
        draw_colour_bar(sheet, PAD + CANVAS + PAD, height - BAR_H + 4, 2 * CANVAS + PAD, vmax, caption)
    return sheet


def write_preview(dataset, out, episode: str | None = None, frames: int = 6, contrast: str = "auto",
                  pick: str = "contact") -> Path:
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"{out}: the preview is written as PNG; give a .png path")
    sheet = render_contact_sheet(dataset, episode=episode, frames=frames, contrast=contrast, pick=pick)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), sheet):
        raise OSError(f"{out}: cv2 could not write the PNG")
    return out
