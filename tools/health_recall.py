"""How well does taxel health find faults planted into REAL tactile series? (htdata/health.py)

    .venv/bin/python tools/health_recall.py DATASET [--seed 0]

For every episode hand of DATASET (e.g. the ingested sample corpus), the
stored maps are sampled at the layout's taxels; the clean series are
classified (every flag there is a false positive), then one fault of each
kind is planted in chosen taxels (dead: a pressed neighbourhood's taxel
zeroed; stuck at 0.4; saturated at 1.0; noisy: +N(0, 0.15)) and, separately,
a cross-talk ghost (30% of a pressed taxel copied along its row, >= 3
columns away). Prints found / planted per kind and the flags nobody planted.
"""

from __future__ import annotations

import argparse

import numpy as np

from htdata import health
from htdata.episodestats import dataset_gloves
from htdata.format import tactile_member
from htdata.reader import DatasetReader


def episode_series(reader: DatasetReader, gloves: dict):
    """(glove, (T,H,W) taxel grids) per episode hand, from the stored maps."""
    for pos, ep in enumerate(reader.episodes):
        first, n = reader.episode_range(pos)
        for hand, layout_id in ep["layouts"].items():
            glove = gloves[layout_id]
            maps = np.stack([reader.decoded(i, (tactile_member(hand),))["tactile"][hand]
                             for i in range(first, first + n)])
            yield glove, glove.rasteriser.sample(maps)


def plant_point_faults(x: np.ndarray, glove, rng) -> dict[str, int]:
    """Plant dead / stuck / saturated / noisy taxels in (T, L) live series `x` (in place); returns kind -> taxel."""
    L = x.shape[1]
    exercised = health._exercised(x, glove.taxels, np.zeros(L, bool))
    candidates = np.flatnonzero(exercised & (x.max(0) > 0.1))
    plants = {"dead": int(rng.choice(candidates))} if candidates.size else {}
    plants.update(zip(("stuck", "saturated", "noisy"), map(int, rng.choice(L, size=3, replace=False))))
    for kind, k in plants.items():
        if kind == "dead":
            x[:, k] = 0
        elif kind == "stuck":
            x[:, k] = 0.4
        elif kind == "saturated":
            x[:, k] = 1.0
        else:
            x[:, k] = np.clip(x[:, k] + rng.normal(0, 0.15, len(x)), 0, 1)
    return plants


def plant_crosstalk(grid: np.ndarray, layout, rng) -> set[tuple[int, int]] | None:
    """Copy 30% of the row's most pressed taxel along the row (in place); the ghost cells, or None."""
    H, W = layout.grid
    rows = [r for r in range(1, H - 1) if all(layout.live_mask[r + d].sum() >= 8 for d in (-1, 0, 1))]
    if not rows:
        return None
    row = int(rng.choice(rows))
    src = int(np.argmax(grid[:, row].max(0)))
    if (grid[:, row, src] > 0.1).sum() < 5:   # the source taxel is hardly pressed: nothing to leak
        return None
    ghosts = [c for c in range(W) if layout.live_mask[row, c] and abs(c - src) >= 3]
    grid[:, row, ghosts] = np.clip(grid[:, row, ghosts] + 0.3 * grid[:, row, src][:, None], 0, 1)
    return {(row, c) for c in ghosts}


def flagged(result: dict) -> dict[str, set]:
    return {c: {tuple(int(v) for v in cell) for cell in result["cells"][c]} for c in health.CLASSES}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    reader = DatasetReader(args.dataset)
    gloves = dataset_gloves(reader)
    rng = np.random.default_rng(args.seed)
    found = dict.fromkeys(health.CLASSES, 0)
    tried = dict.fromkeys(health.CLASSES, 0)
    clean_flags = clean_taxels = extra = 0
    ghost_share, ghost_runs = 0.0, 0
    for glove, grid in episode_series(reader, gloves):
        live = glove.layout.live_mask
        x = np.nan_to_num(grid)[:, live].astype(np.float32)
        clean_flags += sum(health.classify(x, glove.taxels)["counts"].values())
        clean_taxels += x.shape[1]
        plants = plant_point_faults(x, glove, rng)
        cells = flagged(health.classify(x, glove.taxels))
        planted = {tuple(int(v) for v in glove.taxels.cells[k]) for k in plants.values()}
        for kind, k in plants.items():
            tried[kind] += 1
            found[kind] += tuple(int(v) for v in glove.taxels.cells[k]) in cells[kind]
        extra += sum(len(v - planted) for v in cells.values())
        ghost_grid = np.nan_to_num(grid).copy()
        ghosts = plant_crosstalk(ghost_grid, glove.layout, rng)
        if ghosts:
            ct = flagged(health.classify(ghost_grid[:, live], glove.taxels))["crosstalk"]
            ghost_share += len(ct & ghosts) / len(ghosts)
            ghost_runs += 1
    print(f"clean series: {clean_flags} flags over {clean_taxels} taxel-episodes (false positives)")
    print("planted, found / planted: " + ", ".join(f"{k} {found[k]}/{tried[k]}" for k in health.CLASSES
                                                   if k != "crosstalk"))
    print(f"flags nobody planted in the planted runs: {extra}")
    print(f"cross-talk: mean share of ghost taxels found {ghost_share / max(ghost_runs, 1):.2f} "
          f"over {ghost_runs} episode hands")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
