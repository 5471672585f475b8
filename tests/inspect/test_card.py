"""htdata card: a self-contained HTML page (no external resource) with its tables and embedded PNGs, and a Markdown twin."""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser

import cv2
import numpy as np
import pytest

from htdata.cli import main as cli_main
from tests.factories import commit_split
from tests.factories.tactile import LEFT, RIGHT, clean_series, write_taxel_dataset


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.images, self.links, self.tables, self.stack = [], [], 0, []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag not in ("br", "img", "meta"):
            self.stack.append(tag)
        if tag == "img":
            self.images.append(a)
        if tag == "table":
            self.tables += 1
        for key in ("href", "src"):
            if key in a and not a[key].startswith("data:"):
                self.links.append(a[key])
        if tag in ("script", "link", "iframe"):
            self.links.append(tag)

    def handle_endtag(self, tag):
        assert self.stack and self.stack.pop() == tag, f"unbalanced </{tag}>"


def test_card_is_self_contained_with_tables_and_images(tmp_path, capsys):
    root = write_taxel_dataset(tmp_path / "ds", [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": {"right": (RIGHT, clean_series(RIGHT, 32, 1))}},
        {"episode_id": "ep_b", "task": "wipe", "scene": "office",
         "sync": {"hands": {h: {"median_abs_skew_ns": 2_000_000, "offset_ns": 5_000_000} for h in ("left", "right")}},
         "hands": {"right": (RIGHT, clean_series(RIGHT, 31, 2)), "left": (LEFT, clean_series(LEFT, 31, 3))}}])
    commit_split(root, "main", {"train": ["ep_a"], "val": ["ep_b"]})
    out = tmp_path / "card" / "card.html"
    assert cli_main(["card", str(root), str(out)]) == 0
    page = _Page()
    page.feed(out.read_text())
    page.close()
    assert page.links == [] and page.stack == []                   # offline, and every tag closed
    # about (licence, size), sources, sample format; tasks, scenes, gloves, scale, split "main"
    assert page.tables == 8
    # frames/task + frames/scene + 2 gloves x (regions + values) + health + 2 sync + 2 previews
    assert len(page.images) == 11
    for img in page.images:
        assert img["alt"] and img["src"].startswith("data:image/png;base64,")
        png = cv2.imdecode(np.frombuffer(base64.b64decode(img["src"].split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)
        assert png is not None and png.shape[0] >= 60 and png.shape[1] >= 200 and png.std() > 10   # drawn, not blank
    text = out.read_text()
    assert "split main: part" in text and "<td>pour</td>" in text and RIGHT in text
    md = out.with_suffix(".md").read_text()
    assert "| task | episodes |" in md and "](card_files/health.png)" in md
    assert len(list((out.parent / "card_files").glob("*.png"))) == 11
    assert cli_main(["card", str(root), str(tmp_path / "card.txt")]) == 2
    # what a card opens with: name, description, licence (stated or flagged unset), format, how to load
    assert "not stated" in md and "htdata.open(" in md and ("float EXR" in md or "half EXR" in md)
    # the values are said once; how to install is how the README says (no index serves "pip install htdata")
    assert md.count("Values:") == 1 and "pip install htdata" not in md and "pip install . in the htdata checkout" in md
    named = tmp_path / "named.html"
    assert cli_main(["card", str(root), str(named), "--title", "Kitchen gloves", "--description",
                     "Two gloves in a test kitchen.", "--license", "CC-BY-4.0", "--version", "v2"]) == 0
    md = named.with_suffix(".md").read_text()
    assert md.startswith("# Kitchen gloves: version 2") and "Two gloves in a test kitchen." in md
    assert "| licence | CC-BY-4.0 |" in md and "not stated" not in md


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# After the page's load event: how many <img> the browser decoded, and whether anything left the file.
PROBE = """<script>window.addEventListener("load", () => {
  const imgs = [...document.images];
  const out = {images: imgs.length, decoded: imgs.filter(i => i.complete && i.naturalWidth > 0).length,
               width: document.documentElement.scrollWidth,
               remote: performance.getEntriesByType("resource").map(e => e.name).filter(n => !n.startsWith("data:"))};
  const pre = document.createElement("pre"); pre.id = "probe"; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});</script>"""


@pytest.mark.skipif(CHROMIUM is None and not os.environ.get("CI"),
                    reason="no chromium here (.ci/run installs Debian's chromium; CI fails without it)")
def test_card_renders_in_headless_chromium(tmp_path):
    """The card opened by a real browser, offline: every embedded image decodes, nothing is fetched."""
    assert CHROMIUM, "chromium not found: .ci/run installs Debian's chromium package for this test"
    root = write_taxel_dataset(tmp_path / "ds", [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": {"right": (RIGHT, clean_series(RIGHT, 32, 1))}}])
    out = tmp_path / "card.html"
    assert cli_main(["card", str(root), str(out)]) == 0
    probed = tmp_path / "probed.html"
    probed.write_text(out.read_text().replace("</body>", PROBE + "</body>"))
    done = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000", "--dump-dom",
         probed.as_uri()], capture_output=True, text=True, timeout=120)
    found = re.search(r'<pre id="probe">(.*?)</pre>', done.stdout, re.S)
    assert found, f"chromium exit {done.returncode}: {done.stderr[-2000:]}"
    result = json.loads(found.group(1).replace("&quot;", '"'))
    n_img = out.read_text().count("<img ")
    assert result["images"] == n_img >= 5 and result["decoded"] == n_img
    assert result["remote"] == [] and result["width"] > 200


def test_histogram_y_ticks_read_as_counts_and_stay_apart():
    from htdata.inspect.cardplots import _count_label, _y_ticks

    linear = _y_ticks(np.array([0, 2, 4]), log=False)
    assert linear == [(0.0, 0.0), (0.5, 2.0), (1.0, 4.0)]
    log = _y_ticks(np.array([3, 15700, 40]), log=True)
    assert log[0] == (0.0, 0.0) and log[-1] == (1.0, 15700.0)
    fracs = [f for f, _ in log]
    assert all(b - a >= 0.12 for a, b in zip(fracs, fracs[1:]))            # labels never overlap
    assert {c for _, c in log[1:-1]} <= {1.0, 10.0, 100.0, 1000.0}          # powers of ten in between
    assert _y_ticks(np.zeros(5), log=True) == [(0.0, 0.0)]
    assert [_count_label(c) for c in (0, 7, 1500, 2.5e6)] == ["0", "7", "1.5k", "2.5M"]


def test_region_map_names_the_digits_and_the_health_legend_names_no_sensor():
    from htdata.inspect.cardplots import _label_fingers
    from htdata.inspect.healthmap import _legend

    region_map = np.zeros((224, 224), np.uint8)
    region_map[20:60, 100:140] = 1
    region_map[150:200, 40:180] = 2
    panel = np.zeros((224, 224, 3), np.uint8)
    _label_fingers(panel, region_map, {"index.distal": 1, "palm.upper_ulnar": 2})
    assert panel[30:50, 100:140].max() > 200 and panel[165:185, 60:160].max() > 200     # a label in each place
    assert not panel[80:140].any()                                                      # and nowhere else
    assert any("no sensor" in text for _, text in _legend({"maps"}))


# --------------------------------------------------------------------------- a glove-only raw-count dataset


def test_glove_only_card_says_what_the_dataset_is(tmp_path):
    from tests.factories import ingest_rawglove

    root = ingest_rawglove(tmp_path, clips=2)
    md = tmp_path / "card.md"
    assert cli_main(["card", str(root), str(tmp_path / "card.html")]) == 0
    text = md.read_text()
    # Sources: the pipeline is named "rawknit", its episodes' records name the adapter "native": both count
    row = next(line for line in text.splitlines() if line.startswith("| rawknit |"))
    assert row.rstrip().endswith("| 2 |") and "right: rawknit_right_32x32" in row
    assert "paired with egocentric RGB video" not in text and "glove only" in text
    assert "| rgb.jpg |" not in text
    # what the numbers mean: the calibrated rule used, not the old threshold
    meaning = text.split("## What the numbers mean")[1].split("##")[0]
    assert "any taxel above 0.02" not in meaning and "quantisation steps above their noise floor" in meaning
    # a scale suggestion per faint layout, as the line to paste
    assert re.search(r"\| rawknit_left_32x32 \| \d+ \| 0\.\d+ \| 1\.000 \| \[normalise\.rawknit_left_32x32\] "
                     r"scale = [\d.]+ \|", text)


def test_value_histogram_fits_the_data_and_has_ticks():
    from htdata.inspect.card import histogram_chart, value_histogram_chart
    from htdata.inspect.episodestats import HIST_BINS, value_histogram
    from htdata.inspect.stats import fitted_histogram

    values = np.random.default_rng(0).uniform(0, 0.03, 10_000)      # a faint glove: nothing above 0.03
    zeros, hist = value_histogram(np.concatenate([values, np.zeros(50)]))
    h = fitted_histogram(zeros, hist)
    assert h["range"] == [0.0, 0.05] and h["above"] == 0 and sum(h["counts"]) == 10_000 and h["zeros"] == 50
    assert sum(c > 0 for c in h["counts"]) >= 25            # spread over the plot, not one bar at 0
    full = fitted_histogram(0, np.ones(HIST_BINS, np.int64))
    assert full["range"] == [0.0, 1.0] and sum(full["counts"]) == HIST_BINS
    img = value_histogram_chart(h, "faint")
    ticks = histogram_chart([1] * 50, 0.0, 0.05, "t")
    base = ticks.shape[0] - 24
    marks = np.flatnonzero((ticks[base + 2:base + 4].mean(axis=(0, 2)) < 128))  # tick marks under the axis
    assert len(marks) >= 5 and img.shape == ticks.shape
