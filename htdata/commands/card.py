"""`htdata card DATASET OUT.html [--version N]`: a self-contained dataset card (+ OUT.md and OUT_files/)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.commands.outputs import output_path
from htdata.commands.version_arg import version_arg
from htdata.inspect import card

EPILOG = """\
One self-contained HTML page (plus a Markdown twin OUT.md with its images in OUT_files/) that
opens offline: what the dataset holds (frames per task and scene, sources, sample format, how
to load it), how often each hand region is touched, value histograms, taxel health, clock sync
and lag, split sizes and preview strips of a few episodes. Defaults: the current version; the
title is the dataset folder's name unless --title is given. To scrub one episode in time (RGB,
both maps and region curves on one timeline), use htdata view (Rerun).

Examples:
  htdata card data/dataset card.html
  htdata card data/dataset card.html --title "Kitchen tasks v1" --description "46 episodes, two gloves" --license CC-BY-4.0
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", help="committed dataset directory")
    parser.add_argument("out", type=Path, metavar="OUT.html", help="card to write (OUT.md and OUT_files/ beside it)")
    parser.add_argument("--title", default=None, help="dataset name on the card (default: the folder's name)")
    parser.add_argument("--description", default=None,
                        help="a sentence or two on what was recorded (default: the manifest's, else a summary)")
    parser.add_argument("--license", default=None, metavar="SPDX",
                        help="licence of the data, e.g. CC-BY-4.0 (default: the manifest's, else 'not stated')")
    parser.add_argument("--version", type=version_arg, default=None, metavar="N", help="version (default: current)")


def run(args: argparse.Namespace) -> int:
    try:
        if Path(args.out).suffix.lower() == ".html":   # (a wrong suffix is write_card's error, made nowhere)
            output_path(args.out, "card")
        page, md = card.write_card(args.dataset, args.out, version=args.version, title=args.title,
                                   description=args.description, license=args.license)
    except (ValueError, FileNotFoundError, KeyError, OSError) as exc:
        print(f"htdata card: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {page} and {md}")
    return 0
