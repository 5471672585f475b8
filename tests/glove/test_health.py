"""Taxel health: each planted fault is found in its taxels, and clean recordings flag nothing."""

from __future__ import annotations

import numpy as np
import pytest

from htdata.glove import health
from htdata.glove.layouts import load_layout
from tests.factories.tactile import LEFT, RIGHT, clean_series, live_cells

T = 120


def _classify(grids: np.ndarray, layout_id: str) -> dict:
    layout = load_layout(layout_id)
    return health.classify(grids[:, layout.live_mask], health.TaxelGrid.of(layout))


def _flagged(result: dict) -> dict:
    return {name: {tuple(c) for c in cells} for name, cells in result["cells"].items() if cells}


@pytest.mark.parametrize("layout_id", [RIGHT, LEFT])
@pytest.mark.parametrize("seed", range(6))
def test_clean_recordings_flag_nothing(layout_id, seed):
    result = _classify(clean_series(layout_id, T, seed=seed, noise=0.003), layout_id)
    assert result["assessed"] and result["live"] == load_layout(layout_id).num_live
    assert _flagged(result) == {}


def _pressed_cell(grids: np.ndarray, layout_id: str) -> tuple[int, int]:
    """A live cell whose neighbourhood is pressed a lot (where a dead taxel would show)."""
    live = live_cells(layout_id)
    score = [(grids[:, max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] >= 0.2).sum() for r, c in live]
    return tuple(int(v) for v in live[int(np.argmax(score))])


def test_each_planted_fault_is_found_in_its_taxels():
    grids = clean_series(RIGHT, T, seed=3, blobs=5)
    live = [tuple(int(v) for v in c) for c in live_cells(RIGHT)]
    dead = _pressed_cell(grids, RIGHT)
    rng = np.random.default_rng(0)
    others = [c for c in live if c != dead]
    picks = [others[i] for i in rng.choice(len(others), size=3, replace=False)]
    stuck, saturated, noisy = picks
    g = grids.copy()
    g[:, dead[0], dead[1]] = 0.0
    g[:, stuck[0], stuck[1]] = 0.4
    g[:, saturated[0], saturated[1]] = 1.0
    g[:, noisy[0], noisy[1]] = np.clip(g[:, noisy[0], noisy[1]] + rng.normal(0, 0.15, T), 0, 1)
    found = _flagged(_classify(g, RIGHT))
    assert found.get("dead") == {dead}
    assert found.get("stuck") == {stuck}
    assert found.get("saturated") == {saturated}
    assert found.get("noisy") == {noisy}
    assert "crosstalk" not in found


def test_crosstalk_row_is_found_and_real_contact_is_not():
    layout = load_layout(LEFT)
    H, W = layout.grid
    g = np.zeros((T, H, W), np.float32)
    row, col = 15, 3                                   # true contact in the palm at (15, 3), a 3x3 press
    press = np.clip(np.sin(np.arange(T) / 6.0), 0, None) * 0.8
    g[:, row - 1:row + 2, col - 1:col + 2] = press[:, None, None]
    ghost = [c for c in range(col + 3, W) if layout.live_mask[row, c]]
    g[:, row, ghost] += 0.3 * press[:, None]           # the row line lights up far from the press
    found = _flagged(_classify(g, LEFT))
    assert set(found) == {"crosstalk"}
    expected = {(row, c) for c in ghost}
    assert found["crosstalk"] <= expected and len(found["crosstalk"]) >= 0.8 * len(expected)


def test_short_episode_is_not_assessed_and_idle_taxels_are_not_dead():
    short = _classify(np.zeros((health.MIN_FRAMES - 1, 16, 16), np.float32), RIGHT)
    assert not short["assessed"] and sum(short["counts"].values()) == 0
    idle = _classify(np.zeros((T, 16, 16), np.float32), RIGHT)
    assert idle["assessed"] and sum(idle["counts"].values()) == 0
    assert idle["unexercised"] == idle["live"]
    assert health.flagged_share(idle) == 0.0


def _faulty_dataset(root):
    from tests.factories.tactile import write_taxel_dataset
    grids = clean_series(RIGHT, T, seed=3, blobs=5)
    live = [tuple(int(v) for v in c) for c in live_cells(RIGHT)]
    bad = grids.copy()
    for r, c in live[::8]:                              # 1 taxel in 8 stuck: far above WARN_SHARE
        bad[:, r, c] = 0.4
    return write_taxel_dataset(root, [{"episode_id": "clean", "hands": {"right": (RIGHT, grids)}},
                                      {"episode_id": "faulty", "hands": {"right": (RIGHT, bad)}}])


def test_validate_warns_from_the_stats_cache_or_deep(tmp_path):
    from htdata.inspect import stats
    from htdata.validate import validate_dataset
    root = _faulty_dataset(tmp_path / "ds")
    report = validate_dataset(root)
    sensors = report["checks"]["sensors"]
    assert report["ok"] and not [w for w in sensors["warnings"] if w["what"] == "taxel_health"]
    assert any("no cached stats" in s for s in sensors["skipped"])
    deep = validate_dataset(root, deep=True)["checks"]["sensors"]
    assert [(w["episode"], w["hand"]) for w in deep["warnings"] if w["what"] == "taxel_health"] == [("faulty", "right")]
    assert not (root / stats.STATS_DIR).exists()              # validate writes no cache
    summary = stats.dataset_stats(root)
    assert summary["gloves"][0]["health"]["counts"]["stuck"] == len(live_cells(RIGHT)[::8])
    cached = validate_dataset(root)["checks"]["sensors"]
    hits = [w for w in cached["warnings"] if w["what"] == "taxel_health"]
    assert [(w["episode"], w["found"]) for w in hits] == [("faulty", {"stuck": len(live_cells(RIGHT)[::8])})]
    assert report["ok"]


@pytest.mark.parametrize("block", [7, 64, 10**6])
def test_frame_blocks_give_the_same_classes(monkeypatch, block):
    """The per-frame tests run in blocks of frames (memory bounded by the block): the classes do not change."""
    layout = load_layout(LEFT)
    H, W = layout.grid
    g = clean_series(LEFT, 700, seed=5, blobs=4)
    press = np.clip(np.sin(np.arange(700) / 6.0), 0, None) * 0.8
    g[:, 14:17, 2:5] = press[:, None, None]
    g[:, 15, [c for c in range(6, W) if layout.live_mask[15, c]]] += 0.3 * press[:, None]   # a ghost row
    reference = _classify(g, LEFT)
    monkeypatch.setattr(health, "BLOCK_FRAMES", block)
    assert _classify(g, LEFT) == reference and reference["counts"]["crosstalk"] > 0


def test_neighbour_median_is_nanmedian():
    """The sorted-table median equals np.nanmedian over each taxel's neighbours (NaN ignored, none = inf)."""
    rng = np.random.default_rng(0)
    for layout_id in (LEFT, RIGHT):
        taxels = health.TaxelGrid.of(load_layout(layout_id))
        for trial in range(60):
            v = rng.random(len(taxels.cells)).astype(np.float32)
            if trial % 3 == 0:
                v[rng.random(v.size) < 0.3] = np.nan
            if trial % 5 == 0:
                v[:] = np.nan
            if trial % 7 == 0:
                v = np.round(v * 4) / 4                       # ties
            width = max(len(n) for n in taxels.neighbours)
            table = np.full((v.size, width), np.nan)
            for i, near in enumerate(taxels.neighbours):
                table[i, :len(near)] = v[near]
            table[np.isnan(table).all(axis=1)] = np.inf
            assert np.array_equal(health._neighbour_median(v, taxels), np.nanmedian(table, axis=1), equal_nan=True)
