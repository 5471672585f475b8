"""`htdata export lerobot DATASET OUT`: a LeRobot v3.0 dataset from one version of an htdata dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.commands.outputs import output_path
from htdata.commands.version_arg import version_arg
from htdata.export.lerobot import LeRobotExportConfig, export_lerobot

EPILOG = """\
What is written (LeRobot v3.0: meta/info.json, meta/stats.json, meta/tasks.parquet,
meta/episodes/, data/chunk-*/file-*.parquet, videos/<key>/chunk-*/file-*.mp4):
  one LeRobot episode per htdata episode, its task in meta/tasks.parquet;
  observation.images.egocentric     H.264 video of the 224x224 RGB frames
  observation.tactile.<hand>.raw    float32 (rows*cols,): the glove row paired with the frame, as recorded,
                                    row-major (the feature's info.grid gives [rows, cols] to reshape it);
                                    NaN/Inf cells (no taxel there) as 0; a hand recorded with two grid shapes
                                    gets one feature per shape: ...raw_<rows>x<cols>
  observation.tactile.<hand>.map    with --maps: the canonical 224x224 map as grey video (value x --maps-gain x 255)
  observation.present               bool per source (egocentric, tactile.<hand>): is this frame's value real?
  htdata.frame_index                which stored htdata frame the row is (see Time)
  meta/htdata/                      glove layouts, coverage and region masks, split assignment, episode ids

Frames missing a source: LeRobot needs every feature in every frame, so none is dropped.
  RGB-only frame (no glove row)     raw = zeros, observation.present[tactile.<hand>] = False
  tactile-only frame (no RGB)       video repeats the last real RGB frame (black before the first),
                                    observation.present[egocentric] = False
Unpaired full-rate glove rows (those between two frames) are not exported.

Time: LeRobot's loader needs rows on an exact 1/fps grid (it finds a video frame as
round(timestamp x fps)). Row k of an episode (timestamp k/fps) is the stored frame nearest
k/fps on the episode's source clock: on a regular clock every frame once, in order; a gap
repeats the frames beside it. htdata.frame_index names the stored frame of each row.
fps = the episodes' rate (they must agree; default); --fps F lays them on a 1/F grid
instead (frames repeat when F is above the source rate, are skipped below it).

Stats (meta/stats.json) are gathered in the export's single pass. DATASET is only read.
The export is atomic: it is built in OUT's sibling .OUT.partial/ and renamed at the end,
so an interrupted export leaves no OUT (the next run clears the leftover).
--force replaces only a previous export (marked by OUT/.htdata-export.json), never a folder
holding or inside a dataset, nor another non-empty folder; OUT a file or a symlink is refused.
Needs pyarrow: pip install 'htdata[export]'.

Examples:
  htdata export lerobot data/dataset data/lerobot
  htdata export lerobot data/dataset data/lerobot_train --split main --part train --fps 30 --maps
  htdata export lerobot data/dataset data/lerobot_full_rate --tactile-window 8
Open it with LeRobot (pip install lerobot), or check it with lerobot-doctor:
  lerobot-doctor check data/lerobot
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = ("Targets: lerobot (LeRobot v3.0). `htdata export lerobot --help` says what is written.\n\n"
                     "Examples:\n  htdata export lerobot data/dataset data/lerobot\n"
                     "  htdata export lerobot data/dataset data/lerobot_test --split main --part test")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = parser.add_subparsers(dest="target", metavar="TARGET", required=True)
    p = sub.add_parser("lerobot", help="LeRobot v3.0 (parquet + mp4)", epilog=EPILOG,
                       description="Export one version of DATASET as a LeRobot v3.0 dataset in OUT.",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", help="committed htdata dataset directory (read only)")
    p.add_argument("out", type=Path, help="LeRobot dataset directory to create (must not exist; see --force)")
    p.add_argument("--version", type=version_arg, default=None, metavar="N",
                   help="version to export, N or vN (htdata log lists them; default: the current one)")
    p.add_argument("--split", default=None, metavar="NAME",
                   help="order episodes by the parts of split NAME, recorded in info.json splits and "
                        "meta/htdata/split.json (default: no split, every episode)")
    p.add_argument("--part", default=None, metavar="P", help="export only part P of --split (e.g. train)")
    p.add_argument("--fps", type=float, default=None, metavar="F",
                   help="resample to F frames/s (default: the episodes' own rate, no resampling)")
    p.add_argument("--maps", action="store_true", help="also export each hand's canonical map as a video feature")
    p.add_argument("--maps-gain", type=float, default=1.0, metavar="G",
                   help="--maps: grey level = clip(value x G, 0, 1) x 255 (default 1; a raw-count glove's maps press "
                        "to a few percent of 1: the export says when its videos look faint and which G to use)")
    p.add_argument("--tactile-window", type=int, default=None, metavar="K",
                   help="also give each frame the glove rows recorded since the previous frame (the glove at its "
                        "own rate, e.g. 100 Hz beside 30 fps video): observation.tactile.<hand>.window (K rows, "
                        "padded; ..._mask, ..._dt). More than K rows between two frames is an error naming the "
                        "K needed: no row is dropped (default: no window; .raw holds the paired row only)")
    p.add_argument("--crf", type=int, default=18, help="H.264 quality, 0 (lossless) .. 51 (default 18)")
    p.add_argument("--force", action="store_true",
                   help="replace OUT if it is a previous htdata export (never anything else)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        print("htdata export: error: pyarrow is not installed (pip install 'htdata[export]')", file=sys.stderr)
        return 2
    from tqdm import tqdm


    cfg = LeRobotExportConfig(dataset=args.dataset, out=output_path(args.out, "export"), version=args.version, split=args.split,
                              part=args.part, fps=args.fps, maps=args.maps, maps_gain=args.maps_gain, crf=args.crf,
                              force=args.force, tactile_window=args.tactile_window)
    bars = []   # the bar starts when the export knows its total: an error before that prints no empty bar

    def start(total: int) -> None:
        bars.append(tqdm(total=total, unit="frame", desc="export", disable=args.quiet, file=sys.stderr))

    try:
        summary = export_lerobot(cfg, progress=lambda n=1: bars and bars[0].update(n), on_total=start)
    except (ValueError, FileNotFoundError, FileExistsError, KeyError, OSError) as exc:
        for bar in bars:
            bar.close()
        print(f"htdata export: error: {exc}", file=sys.stderr)
        return 2
    for bar in bars:
        bar.close()
    print(f"wrote {summary['out']}: LeRobot v3.0, {summary['episodes']} episodes, {summary['frames']} frames "
          f"at {summary['fps']} fps{' (resampled)' if summary['resampled'] else ''}, {summary['tasks']} tasks, "
          f"hands {', '.join(summary['hands']) or 'none'}, {summary['bytes'] / 1e6:.1f} MB")
    for key, faint in summary.get("faint_maps", {}).items():
        print(f"warning: {key}: the map video is faint: 99.9% of its lit pixels are below grey level "
              f"{faint['p99_9']} of 255 at --maps-gain {args.maps_gain:g}; --maps-gain {faint['gain']:g} puts them "
              f"near white (htdata stats suggests a scale for the maps themselves)", file=sys.stderr)
    return 0
