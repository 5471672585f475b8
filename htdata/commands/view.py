"""`htdata view DATASET [--episode ID] [--version N] [--split NAME --part P] [--save FILE.rrd] [--web]`."""

from __future__ import annotations

import argparse
import sys
import time

from htdata.commands.outputs import output_path
from htdata.commands.version_arg import version_arg
from htdata.inspect import preview, view

EPILOG = """\
Scrub one episode in Rerun (rerun.io), everything on one timeline (frame, and seconds since the
episode's first frame): the egocentric RGB as stored (its JPEG), each hand's tactile map coloured
as `htdata preview` colours it (hatched = no sensor there, white = region outlines), the mean
value of each hand region (thumb .. palm) over time, the raw glove grid of raw-count gloves,
bend values where the glove has them, and the RGB - tactile skew of each frame. A glove-only
episode has no RGB view; a hand the episode lacks has no view.
Without --save the Rerun viewer opens (--web: served to a browser, until Ctrl-C); with --save
the recording is written to FILE.rrd and nothing opens (open it later: rerun FILE.rrd).
Defaults: the first episode (of --split/--part when given), the current version, auto contrast.
Needs rerun-sdk: pip install '.[view]'.

Examples:
  htdata view data/dataset
  htdata view data/dataset --episode ot-home_kitchen_p1-demo_19 --save episode.rrd
  htdata view data/dataset --split main --part test --web
  htdata view data/dataset --web --no-browser --web-port 8090 --grpc-port 8876
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", help="committed dataset directory (or URL)")
    parser.add_argument("--episode", default=None, metavar="ID",
                        help="episode id (default: the first episode, of the split part when given)")
    parser.add_argument("--version", type=version_arg, default=None, metavar="N", help="version (default: current)")
    parser.add_argument("--split", default=None, metavar="NAME", help="choose among a split's episodes (with --part)")
    parser.add_argument("--part", default=None, metavar="P", help="the split's part, e.g. train or test")
    parser.add_argument("--contrast", choices=preview.CONTRASTS, default="auto",
                        help="map colour scale, as `htdata preview --contrast` (default auto: 0..the dataset's "
                             "p99 of positive taxel values when that is below "
                             f"{preview.AUTO_QUANTILE_BELOW}, else 0..1)")
    sink = parser.add_mutually_exclusive_group()
    sink.add_argument("--save", default=None, metavar="FILE.rrd",
                      help="write the recording to FILE.rrd and open nothing (default: open the viewer)")
    sink.add_argument("--web", action="store_true",
                      help="serve the web viewer and open a browser on it, until Ctrl-C (default: the native viewer)")
    parser.add_argument("--web-port", type=int, default=view.WEB_PORT, metavar="N",
                        help=f"--web: the page's port (default {view.WEB_PORT})")
    parser.add_argument("--grpc-port", type=int, default=view.GRPC_PORT, metavar="N",
                        help=f"--web: the port the page reads the episode from (default {view.GRPC_PORT}); "
                             "`rerun rerun+http://127.0.0.1:N/proxy` connects to it too")
    parser.add_argument("--no-browser", action="store_true",
                        help="--web: serve without opening a browser (open the printed URL yourself)")


def run(args: argparse.Namespace) -> int:
    try:
        view.load_rerun()
        save = output_path(args.save, "view") if args.save else None
        result = view.view_episode(args.dataset, episode=args.episode, version=args.version, split=args.split,
                                   part=args.part, contrast=args.contrast, save=save, web=args.web,
                                   open_browser=not args.no_browser, web_port=args.web_port,
                                   grpc_port=args.grpc_port)
    except (ValueError, ImportError, FileNotFoundError, OSError) as exc:
        print(f"htdata view: error: {exc}", file=sys.stderr)
        return 2
    plan = result.plan
    what = (f"{plan.episode_id} ({plan.num_frames} frames, hands: {', '.join(plan.hands) or 'none'}"
            f"{'' if plan.rgb else ', glove only'}; colour scale 0..{plan.vmax:.3g}, {plan.contrast} contrast)")
    if args.save:
        print(f"wrote {result.target}: {what}; open it with: rerun {result.target}")
        return 0
    if not args.web:
        print(f"sent {what} to the Rerun viewer")
        return 0
    print(f"serving {what} at {result.target} in the web viewer (data: {result.data_url}); Ctrl-C to stop",
          flush=True)
    stream = result.stream   # Rerun serves the data port only while its stream lives: hold it until Ctrl-C
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        del stream
