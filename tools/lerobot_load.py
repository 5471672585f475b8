"""Open an htdata LeRobot export with LeRobot's own loader (lerobot-dataset's LeRobotDataset) and print items.

    .venv-ledataset/bin/python tools/lerobot_load.py data/lerobot [--json OUT]

Runs in its own venv (`make lerobot-load`: lerobot-dataset + torch 2.14.1 + torchvision 0.29.1,
~6 GB; not part of CI). Loads the dataset offline from disk, reads item 0, an item in the middle
of an episode with a delta_timestamps window over the tactile rows and the video, and checks
what LeRobot returns against the export's own parquet (no htdata code is imported here):
shapes, dtypes, the window's padding flags at an episode start, raw rows equal to the parquet's.
Exit 0 when everything holds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("export", type=Path)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    from ledataset.datasets.lerobot_dataset import LeRobotDataset

    info = json.loads((args.export / "meta/info.json").read_text())
    fps = info["fps"]
    raw_keys = [k for k, f in info["features"].items() if k.endswith(".raw") or ".raw_" in k]
    video = "observation.images.egocentric"
    window = {video: [-2 / fps, -1 / fps, 0.0], **{k: [-2 / fps, -1 / fps, 0.0] for k in raw_keys}}
    plain = LeRobotDataset("htdata/export", root=args.export, video_backend="torchcodec")
    windowed = LeRobotDataset("htdata/export", root=args.export, video_backend="torchcodec", delta_timestamps=window)
    load_s = time.perf_counter() - t0
    data = pa.concat_tables([pq.read_table(f) for f in sorted((args.export / "data").rglob("*.parquet"))])
    problems = []
    if len(plain) != info["total_frames"] or plain.num_episodes != info["total_episodes"]:
        problems.append(f"LeRobotDataset has {len(plain)} frames / {plain.num_episodes} episodes, info.json "
                        f"{info['total_frames']} / {info['total_episodes']}")
    item = plain[0]
    frame = item[video]
    if tuple(frame.shape) != (3, 224, 224) or str(frame.dtype) != "torch.float32":
        problems.append(f"item 0 {video}: {tuple(frame.shape)} {frame.dtype}, expected (3, 224, 224) float32")
    for key in raw_keys:
        want = np.asarray(data.column(key)[0].as_py(), np.float32)
        if not np.array_equal(item[key].numpy(), want):
            problems.append(f"item 0 {key} differs from the parquet row")
    # a window at an episode start: the two earlier frames are padding
    first = windowed[0]
    if first[f"{video}_is_pad"].tolist() != [True, True, False]:
        problems.append(f"window at frame 0: {video}_is_pad {first[f'{video}_is_pad'].tolist()}")
    # a window inside the first episode long enough: real frames, raw rows = parquet rows r-2..r
    ep_len = data.column("frame_index").to_pylist().index(0, 1) if 0 in data.column("frame_index").to_pylist()[1:] \
        else len(data)
    r = min(10, ep_len - 1)
    mid = windowed[r]
    if mid[f"{video}_is_pad"].tolist() != [False, False, False] or tuple(mid[video].shape) != (3, 3, 224, 224):
        problems.append(f"window at row {r}: pad {mid[f'{video}_is_pad'].tolist()}, video {tuple(mid[video].shape)}")
    for key in raw_keys:
        want = np.asarray([data.column(key)[q].as_py() for q in (r - 2, r - 1, r)], np.float32)
        if not np.array_equal(mid[key].numpy(), want):
            problems.append(f"window at row {r}: {key} differs from parquet rows {r - 2}..{r}")
    summary = {"load_s": round(load_s, 1), "frames": len(plain), "episodes": plain.num_episodes,
               "item0": {k: (f"{tuple(v.shape)} {v.dtype}" if hasattr(v, "shape") else v) for k, v in item.items()},
               "window_row": r, "window_pad": mid[f"{video}_is_pad"].tolist(),
               "window_shapes": {k: tuple(mid[k].shape) for k in window}}
    print(json.dumps(summary, indent=1, default=str))
    for line in problems:
        print(f"FAIL {line}")
    if args.json:
        args.json.write_text(json.dumps({"problems": problems, **summary}, indent=1, default=str))
    print(f"lerobot-load: {'OK' if not problems else f'{len(problems)} problem(s)'}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
