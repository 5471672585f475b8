"""Raw-count glove clips measured by their counts alone: a real-glove folder given by an explicit path, or the
sample raw-count glove's corpus (htdata/synthetic/rawglove.py), as one type (`RealClip`).

A real-glove folder holds `clips/manifest.jsonl` (clip, file, label, fps,
frames), `clips/<file>.npz` (key `counts`, (T, 2, H, W) raw counts, hand 0 =
left) and `layouts/*.json` (one layout per hand, found by its "hand"). The
toolkit never reads such a folder on its own: the bench sections
(realglove, realglovecells) and the tests that name it do.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError
from htdata.format.canvas import HANDS
from htdata.glove.layouts import Layout, load_layout
from htdata.synthetic.rawglove import corpus_clips, glove_layout


@dataclass
class RealClip:
    clip: int
    label: str
    fps: float
    counts: np.ndarray       # (T, 2, H, W) raw counts as recorded, hand 0 = left

    def hand(self, hand: str) -> np.ndarray:
        return self.counts[:, HANDS.index(hand)]


def load_real_glove(folder: str | Path) -> tuple[list[RealClip], dict[str, Layout]]:
    """(clips, {hand: layout}) of a real-glove folder (module docstring); ArgumentError names what is missing."""
    root = Path(folder)
    manifest = root / "clips" / "manifest.jsonl"
    if not manifest.is_file():
        raise ArgumentError(f"{root}: no clips/manifest.jsonl (a real-glove folder holds clips/ and layouts/)")
    layouts = {}
    for path in sorted((root / "layouts").glob("*.json")):
        layout = load_layout(str(path))
        layouts.setdefault(layout.hand, layout)
    if set(layouts) != set(HANDS):
        raise ArgumentError(f"{root}/layouts: need a layout per hand, found {sorted(layouts) or 'none'}")
    clips = []
    for line in manifest.read_text().splitlines():
        if not line.strip():
            continue
        entry = json.loads(line)
        with np.load(root / "clips" / entry["file"]) as z:
            counts = np.asarray(z["counts"])
        if counts.ndim != 4 or counts.shape[1] != 2 or counts.shape[2:] != layouts["left"].grid:
            raise ArgumentError(f"{root}/clips/{entry['file']}: counts {counts.shape}, expected (T, 2, "
                                f"{layouts['left'].grid[0]}, {layouts['left'].grid[1]})")
        clips.append(RealClip(int(entry["clip"]), str(entry["label"]), float(entry["fps"]), counts))
    return clips, layouts


def sample_glove_clips(seed: int = 0) -> tuple[list[RealClip], dict[str, Layout]]:
    """The sample raw-count glove's corpus (htdata/synthetic/rawglove.py) as clips of this module: measured the
    same way as the real ones, by their counts alone."""
    _, clips = corpus_clips(seed)
    out = [RealClip(k, c.name, float(c.fps), np.stack([c.counts[h] for h in HANDS], axis=1))
           for k, c in enumerate(clips)]
    return out, {h: glove_layout(h) for h in HANDS}
