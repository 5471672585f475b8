"""htdata preview: a PNG contact sheet of the expected size and layout."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from htdata.cli import main as cli_main
from htdata.inspect import preview as pv
from tests.factories import PREVIEW_EPISODES as EPISODES
from tests.factories import write_synthetic_dataset


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    cov = np.zeros((224, 224), np.uint8)
    cov[20:200, 30:190] = 1
    return write_synthetic_dataset(tmp_path_factory.mktemp("pv") / "ds", EPISODES,
                                   coverages={"test_full": cov})


def _panel(sheet: np.ndarray, row: int, col: int) -> np.ndarray:
    y = pv.TITLE_H + pv.HEADER_H + row * (pv.CANVAS + pv.PAD)
    x = pv.PAD + col * (pv.CANVAS + pv.PAD)
    return sheet[y:y + pv.CANVAS, x:x + pv.CANVAS]


def test_frame_positions_are_evenly_spaced_and_bounded():
    assert pv.frame_positions(7, 4).tolist() == [0, 2, 4, 6]
    assert pv.frame_positions(3, 6).tolist() == [0, 1, 2]   # shorter episode: all frames
    assert pv.frame_positions(1, 6).tolist() == [0]
    with pytest.raises(ValueError, match="--frames"):
        pv.frame_positions(5, 0)
    with pytest.raises(ValueError, match="at least one frame"):
        pv.frame_positions(0, 3)


def test_region_outline_marks_label_changes_only():
    labels = np.zeros((6, 6), np.uint8)
    labels[:, 3:] = 1
    edge = pv.region_outline(labels)
    assert edge[:, 2].all() and edge.sum() == 6
    assert not pv.region_outline(np.full((5, 5), 4, np.uint8)).any()


def test_cli_writes_png_of_expected_size(ds, tmp_path):
    out = tmp_path / "sheet.png"
    assert cli_main(["preview", str(ds), "--episode", "ep_r", "--frames", "4", str(out)]) == 0
    img = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert img.shape[:2] == pv.sheet_size(4) == (pv.TITLE_H + pv.HEADER_H + 4 * 232 + 8 + pv.BAR_H, 8 + 3 * 232)


def test_absent_hand_is_a_grey_panel_and_tactile_is_drawn(ds):
    sheet = pv.render_contact_sheet(ds, episode="ep_r", frames=3, pick="even")
    left = _panel(sheet, 0, 1)
    grey = np.all(left == pv.ABSENT_GREY, axis=2).mean()
    assert grey > 0.9          # the rest is the "no left hand" text
    assert (left != pv.ABSENT_GREY).any()
    right = _panel(sheet, 0, 2)
    assert (right == pv.OUTLINE).all(axis=2).any()        # region outlines
    assert np.all(right[5, 5] == (110, 110, 110)) or np.all(right[5, 5] < 160)  # uncovered: shaded
    # the RGB panel is the decoded frame (BGR on the sheet)
    from htdata.read.reader import DatasetReader
    with DatasetReader(ds) as r:
        rgb = r.decoded(r.locate("ep_r", 0))["rgb"]
    assert np.array_equal(_panel(sheet, 0, 0)[40:], cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)[40:])


def test_two_hands_and_single_frame_episode(ds):
    sheet = pv.render_contact_sheet(ds, episode="ep_lr", frames=10)
    assert sheet.shape[:2] == pv.sheet_size(3)
    assert not np.all(_panel(sheet, 1, 1) == pv.ABSENT_GREY, axis=2).mean() > 0.5
    one = pv.render_contact_sheet(ds, episode="ep_one", frames=5)
    assert one.shape[:2] == pv.sheet_size(1)
    assert np.all(_panel(one, 0, 2) == pv.ABSENT_GREY, axis=2).mean() > 0.9


def test_render_tactile_shows_nonfinite_and_shades_uncovered():
    tmap = np.zeros((224, 224), np.float32)
    tmap[100, 100] = np.nan
    tmap[50, 50] = 1.0
    cov = np.zeros((224, 224), np.uint8)
    cov[40:, 40:] = 1
    panel = pv.render_tactile(tmap, cov, np.zeros((224, 224), bool))
    assert tuple(panel[100, 100]) == pv.NONFINITE
    assert panel[50, 50].sum() > 500                      # inferno(1.0) is pale yellow
    assert tuple(panel[0, 0]) == (110, 110, 110)          # hatch line in the uncovered area
    # inferno(0) is near-black: dimmed to 35% and lifted by 70 it becomes a dark grey
    assert np.all(np.abs(panel[0, 1].astype(int) - 70) <= 2)


def test_errors_unknown_episode_and_bad_suffix(ds, tmp_path, capsys):
    assert cli_main(["preview", str(ds), "--episode", "nope", str(tmp_path / "a.png")]) == 2
    assert "no episode 'nope'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="give a .png path"):
        pv.write_preview(ds, tmp_path / "a.jpg")


def _bar(sheet: np.ndarray) -> np.ndarray:
    y = sheet.shape[0] - pv.BAR_H + 4
    x = pv.PAD + pv.CANVAS + pv.PAD
    return sheet[y:y + pv.BAR_STRIP_H, x:x + 2 * pv.CANVAS + pv.PAD]


def test_colour_bar_is_drawn_with_its_values(ds):
    sheet = pv.render_contact_sheet(ds, episode="ep_lr", frames=2)
    strip = _bar(sheet)
    ramp = cv2.applyColorMap(np.linspace(0, 255, strip.shape[1]).astype(np.uint8)[None, :], cv2.COLORMAP_INFERNO)[0]
    assert np.array_equal(strip[0], ramp) and np.array_equal(strip[-1], ramp)     # the inferno scale, left to right
    labels = sheet[sheet.shape[0] - pv.BAR_H + 4 + pv.BAR_STRIP_H + 5:, pv.PAD + pv.CANVAS:]
    assert (labels.mean(axis=2) > 120).sum() > 100                               # tick values + caption drawn
    with pytest.raises(ValueError, match="--contrast"):
        pv.render_contact_sheet(ds, episode="ep_lr", frames=2, contrast="bogus")


def test_quantile_contrast_brightens_faint_maps(tmp_path):
    from tests.factories.tactile import RIGHT, clean_series, write_taxel_dataset
    faint = clean_series(RIGHT, 8, seed=4, blobs=4) * 0.15                    # contact at 0.02-0.15
    root = write_taxel_dataset(tmp_path / "faint", [{"episode_id": "f", "hands": {"right": (RIGHT, faint)}}])
    vmax = pv.contrast_vmax(root, "quantile")
    assert 0.05 < vmax < 0.2 and pv.contrast_vmax(root, "fixed") == 1.0
    fixed = pv.render_contact_sheet(root, frames=8, contrast="fixed")
    quant = pv.render_contact_sheet(root, frames=8, contrast="quantile")
    rows = range(8)
    lum = [np.mean([_panel(s, r, 2).astype(float).sum(axis=2).mean() for r in rows]) for s in (fixed, quant)]
    assert lum[1] > lum[0] + 20
    def hottest(panel: np.ndarray) -> int:
        lum = panel.astype(int).sum(axis=2)
        return int(lum[~(panel == pv.OUTLINE).all(axis=2)].max())      # outlines are white by design
    hot = [max(hottest(_panel(s, r, 2)) for r in rows[1:]) for s in (fixed, quant)]   # row 0 carries region names
    assert hot[0] < 400 < hot[1]                                              # faint stays dark unless stretched
    assert cli_main(["preview", str(root), str(tmp_path / "q.png"), "--contrast", "quantile"]) == 0


def test_contact_pick_takes_the_frames_with_most_contact_in_time_order():
    n = 40
    frame_max = np.zeros(n)
    frame_max[[5, 6, 7, 30]] = [0.2, 0.5, 0.3, 0.4]
    contact = (frame_max > 0).astype(int)
    stats = {"hands": {"right": {"frame_index": list(range(n)), "frame_max": frame_max.tolist(),
                                 "frame_contact": contact.tolist()}}}
    # 2 rows: the peak (6) and the next best at least n/(2*2) = 10 frames away (30), not its neighbour 7
    assert pv.contact_positions(stats, n, 2).tolist() == [6, 30]
    # more rows than frames in contact: every row still drawn (contact frames first, then even spacing)
    four = pv.contact_positions(stats, n, 4).tolist()
    assert len(four) == 4 and {6, 30} <= set(four) and four == sorted(four)
    none = {"hands": {"right": {**stats["hands"]["right"], "frame_contact": [0] * n}}}
    assert pv.contact_positions(none, n, 3).tolist() == pv.frame_positions(n, 3).tolist()


def test_auto_contrast_stretches_weak_gloves_only(tmp_path):
    from tests.factories.tactile import RIGHT, clean_series, write_taxel_dataset
    faint = write_taxel_dataset(tmp_path / "faint", [{"episode_id": "f", "hands": {
        "right": (RIGHT, clean_series(RIGHT, 8, seed=4, blobs=4) * 0.15)}}])
    strong = write_taxel_dataset(tmp_path / "strong", [{"episode_id": "s", "hands": {
        "right": (RIGHT, np.clip(clean_series(RIGHT, 8, seed=4, blobs=4) * 3.0, 0, 1))}}])
    used, vmax = pv.contrast_scale(faint, "auto")
    assert used == "quantile" and vmax < pv.AUTO_QUANTILE_BELOW
    assert pv.contrast_scale(strong, "auto") == ("fixed", 1.0)


def test_cli_prints_the_colour_bar_range(tmp_path, capsys):
    from tests.factories.tactile import RIGHT, clean_series, write_taxel_dataset
    faint = write_taxel_dataset(tmp_path / "faint", [{"episode_id": "f", "hands": {
        "right": (RIGHT, clean_series(RIGHT, 8, seed=4, blobs=4) * 0.15)}}])
    assert cli_main(["preview", str(faint), str(tmp_path / "f.png")]) == 0
    out = capsys.readouterr().out
    used, vmax = pv.contrast_scale(faint, "auto")
    assert f"colour bar 0..{vmax:.3g} (quantile contrast" in out and "frames: before / during / after contact" in out


@pytest.fixture(scope="module")
def glove_only(tmp_path_factory):
    from tests.factories import ingest_rawglove
    return ingest_rawglove(tmp_path_factory.mktemp("pv_glove"), clips=1)


def test_glove_only_sheet_has_no_rgb_column_and_rows_show_clip_time(glove_only):
    from htdata.read.reader import DatasetReader

    sheet = pv.render_contact_sheet(glove_only, frames=3, pick="even", contrast="quantile")
    assert sheet.shape[:2] == pv.sheet_size(3, rgb=False)
    assert sheet.shape[1] == pv.PAD + 2 * (pv.CANVAS + pv.PAD) < pv.sheet_size(3)[1]
    for col in (0, 1):                                   # both columns are the gloves: no grey "no RGB" panel
        assert np.all(_panel(sheet, 0, col) == pv.ABSENT_GREY, axis=2).mean() < 0.1
    with DatasetReader(glove_only) as r:
        first, n = r.episode_range(0)
        assert n > 82 and round(r.episodes[0]["fps"]) == 30
        assert pv.clip_time_s(r, first, first + 82) == pytest.approx(82 / 30, abs=1e-3)     # 2.733 s, not 0
        assert pv.clip_time_s(r, first, first) == 0.0


def test_colour_bar_caption_wraps_inside_the_sheet(glove_only, tmp_path):
    from tests.factories.tactile import RIGHT, clean_series, write_taxel_dataset
    with_rgb = write_taxel_dataset(tmp_path / "faint", [{"episode_id": "f", "hands": {
        "right": (RIGHT, clean_series(RIGHT, 8, seed=4, blobs=4) * 0.15)}}])
    caption = ("tactile value 0..0.778 (p99 of the dataset's positive taxel values; above saturates); "
               "frames: evenly spaced (no stats for this dataset)")
    width = 2 * pv.CANVAS + pv.PAD
    lines = pv.wrap_text(caption, width)
    assert 1 < len(lines) <= pv.BAR_CAPTION_LINES and " ".join(lines) == caption
    assert all(cv2.getTextSize(line, pv.FONT, pv.BAR_FONT, 1)[0][0] <= width for line in lines)
    assert pv.wrap_text("word " * 200, 100)[-1].endswith("...")
    for root in (with_rgb, glove_only):                   # the long quantile caption on both sheet widths
        sheet = pv.render_contact_sheet(root, frames=2, contrast="quantile")
        band = sheet[sheet.shape[0] - pv.BAR_H:]
        assert not (band[:, -pv.PAD:] > 120).any()        # nothing drawn into the right margin (it was cut there)
        assert not (band[-2:] > 120).any()                # nor onto the bottom edge
        assert (band[pv.BAR_STRIP_H + 36:, :] > 120).any(axis=2).sum() > 100   # the caption's lines are there


def _contact_stats(n: int, on: range) -> dict:
    contact = np.zeros(n, int)
    contact[list(on)] = 1
    return {"hands": {"right": {"frame_index": list(range(n)), "frame_max": (contact * 0.5).tolist(),
                                "frame_contact": contact.tolist()}}}


def test_phases_pick_shows_the_grasp_begin_hold_and_end():
    """The default rows: one frame before the first contact, the rest spread over the contact span,
    one after the last (the six near-identical frames of one grasp were the old default)."""
    rows = pv.phase_positions(_contact_stats(60, range(20, 41)), 60, 6).tolist()
    assert rows == sorted(rows) and len(rows) == 6
    assert rows[0] < 20 and rows[-1] > 40 and all(20 <= r <= 40 for r in rows[1:-1])
    assert rows[-2] - rows[1] >= 15                       # spread over the hold, not bunched at its peak
    mid = pv.phase_positions(_contact_stats(60, range(0, 41)), 60, 6).tolist()   # starts mid-grasp
    assert mid[0] <= 5 and mid[-1] > 40 and len(mid) == 6     # no lead-in: the hold from its start
    assert pv.phase_positions(_contact_stats(30, range(0)), 30, 4).tolist() == pv.frame_positions(30, 4).tolist()
    short = pv.phase_positions(_contact_stats(30, range(10, 12)), 30, 6).tolist()  # a short touch: rows still drawn
    assert len(short) == 6 and {10, 11} <= set(short)


def test_region_names_sit_on_their_regions(ds):
    import htdata
    from htdata.glove.canonical import PART_NAMES

    parts = htdata.open(ds).region_map
    labels = dict(pv.region_labels(parts))
    assert set(labels) == set(PART_NAMES.values())
    ids = {name: pid for pid, name in PART_NAMES.items()}
    assert all(parts[y, x] == ids[name] for name, (x, y) in labels.items())
    sheet = pv.render_contact_sheet(ds, frames=2)
    assert sheet.shape[:2] == pv.sheet_size(2, rgb=True)
