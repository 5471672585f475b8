"""`htdata preview DATASET OUT.png`: a contact sheet of one episode (RGB | left | right tactile)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.commands.outputs import output_path
from htdata.inspect import preview

EPILOG = """\
A contact sheet of one episode: rows over time (by default the grasp's phases: a frame before the
first contact, frames over the contact span, a frame after the last; --pick contact: the N
frames with the most contact; --pick even: N frames evenly spaced), each labelled with its
frame number and clip time (seconds
since the episode's first frame); columns RGB | left tactile | right tactile (no RGB column when
the episode has no video). Tactile maps are colour-mapped (black = 0, pale yellow = the top of
the colour bar) with the hand's region outlines, named on the first row; grey hatching = where
the glove has no sensor (the legend under the sheet says so);
a grey panel = a hand the episode does not have; magenta = a non-finite value (damage).
--contrast quantile stretches the colours to the dataset's 99th percentile so faint contact shows.
Defaults: the two-handed episode with the most contact, 6 frames, auto contrast.
To scrub a whole episode in time instead (RGB, both maps and region curves on one timeline):
htdata view, in Rerun.

Examples:
  htdata preview data/dataset preview.png
  htdata preview data/dataset ep.png --episode ot-home_kitchen_p1-demo_19 --frames 10 --contrast quantile
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("out", type=Path, metavar="OUT.png", help="contact sheet to write")
    parser.add_argument("--episode", default=None, metavar="ID",
                        help="episode id (default: the two-handed episode with the most contact)")
    parser.add_argument("--frames", type=int, default=6, metavar="N", help="rows: N frames (default 6)")
    parser.add_argument("--pick", choices=preview.PICKS, default="phases",
                        help="phases (default): before / during / after contact; contact: the N frames with the "
                             "most contact (each glove hand's contact rule: docs/USAGE.md), in time order; even: "
                             "N frames evenly spaced")
    parser.add_argument("--contrast", choices=preview.CONTRASTS, default="auto",
                        help="auto (default): quantile when the dataset's p99 of positive taxel values is below "
                             f"{preview.AUTO_QUANTILE_BELOW}, else fixed; fixed: colour scale 0..1; quantile: "
                             "0..that p99, so faint contact shows (uses `htdata stats`, cached). Example: "
                             "htdata preview DATA/dataset sheet.png --frames 4 --contrast fixed")


def run(args: argparse.Namespace) -> int:
    try:
        used, vmax = preview.contrast_scale(args.dataset, args.contrast)
        out = preview.write_preview(args.dataset, output_path(args.out, "preview"), episode=args.episode, frames=args.frames,
                                     contrast=used, pick=args.pick)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"htdata preview: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}; colour bar 0..{vmax:.3g} ({used} contrast"
          f"{', p99 of the positive taxel values' if used == 'quantile' else ''}; frames: "
          f"{preview.PICK_WORDS[args.pick]})")
    return 0
