"""`htdata layouts suggest` names what it saw and what it could not see (issue 43, item 4): the glove's direction
(value.convention), the parts of the grid no recording pressed, and strips cut along the finger only."""

from __future__ import annotations

import json

import numpy as np
import pytest

from htdata.cli import main
from htdata.glove.activity import CellActivity, seen_direction
from htdata.glove.layouts import load_layout


@pytest.fixture(scope="module")
def sample_clips():
    from htdata.synthetic.rawglove import corpus_clips

    return corpus_clips(0)[1]


def _save(tmp_path, name: str, rows: np.ndarray):
    path = tmp_path / f"{name}.npy"
    np.save(path, np.asarray(rows, np.float32))
    return str(path)


def _boxes(layout) -> list[tuple[int, int, int, int]]:
    return sorted((b.rows[0], b.rows[1], b.cols[0], b.cols[1]) for b in layout.blocks)


def test_suggest_writes_inverted_for_a_glove_whose_counts_fall_with_pressure(tmp_path, sample_clips, capsys):
    """The same presses recorded by a glove whose counts fall (1023 - raw): value.convention "inverted" and the
    blocks of the direct glove."""
    direct = [_save(tmp_path, f"direct_{k}", c.counts["right"]) for k, c in enumerate(sample_clips)]
    inverted = [_save(tmp_path, f"inverted_{k}", 1023.0 - c.counts["right"].astype(np.float32))
                for k, c in enumerate(sample_clips)]
    assert main(["layouts", "suggest", *direct, str(tmp_path / "direct.json"), "--hand", "right"]) == 0
    assert main(["layouts", "suggest", *inverted, str(tmp_path / "inverted.json"), "--hand", "right"]) == 0
    printed = capsys.readouterr().out
    a, b = load_layout(tmp_path / "direct.json"), load_layout(tmp_path / "inverted.json")
    assert a.value["convention"] == "direct" and b.value["convention"] == "inverted"
    assert _boxes(a) == _boxes(b) and len(a.blocks) >= 9
    assert "value.convention inverted as the recordings show" in printed and "GUESS" not in printed
    assert "as the recordings show" in json.loads((tmp_path / "inverted.json").read_text())["notes"]


def test_the_direction_is_a_guess_said_so_when_the_recordings_do_not_tell(tmp_path, capsys):
    """A patch that rises and one that falls as much: either could be the presses; suggest says it guessed, and a
    stated --convention is written as stated."""
    rng = np.random.default_rng(1)
    x = 550 + rng.uniform(-20, 20, (1, 16, 16)) + rng.normal(0, 0.5, (600, 16, 16))
    press = 80.0 * (np.arange(600) % 200 // 16 == 6)[:, None, None]     # three half-second presses
    x[:, 0:4, 0:4] += press
    x[:, 8:12, 8:12] -= press
    acts = CellActivity((16, 16))
    acts.add(x.astype(np.float32))
    seen = seen_direction([acts], None)
    assert seen.inverted is None and seen.falls_as_direct == seen.falls_as_inverted == 16
    rec = _save(tmp_path, "rec", x)
    assert main(["layouts", "suggest", rec, str(tmp_path / "guess.json"), "--hand", "left"]) == 0
    out = capsys.readouterr().out
    assert "WARNING: value.convention direct is a GUESS, CHECK IT" in out
    assert "GUESS" in load_layout(tmp_path / "guess.json").notes
    assert main(["layouts", "suggest", rec, str(tmp_path / "stated.json"), "--hand", "left",
                 "--convention", "inverted"]) == 0
    assert load_layout(tmp_path / "stated.json").value["convention"] == "inverted"
    assert "as stated (--convention" in capsys.readouterr().out
