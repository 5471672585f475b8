"""Broken control corpora: the sample corpus with its video wrong in one known way.

For proving that a trainer's checks catch a broken pipeline (`make train-smoke-mispaired`,
`-reversed`, `-lagged`); never for training. The tactile data is always the corpus's own:

- mis-paired (`htdata sample --mispair-rgb`): each episode's video shows the world of another
  episode of its format (half the format's list away, so another task), each frame at a random
  moment of it, as a pipeline that mixed up episodes would store it;
- lagged (`--rgb-lag-frames K`): the video lags the glove by K video frames (frame i shows the
  moment K frames earlier), as a pipeline with an uncorrected clock offset would;
- reversed (`--reverse-rgb`): each episode's video played backwards.

`mark_controls` writes the choice into the planned episodes' `extra`; `control_video` renders it.
"""

from __future__ import annotations

import numpy as np

from htdata.synthetic.tasks import stable_hash
from htdata.synthetic.world import World


def mark_controls(episodes: list, mispair_rgb: bool, rgb_lag_frames: int, reverse_rgb: bool) -> list:
    """The planned episodes of one format with the control corpus's choice in each `extra`."""
    if mispair_rgb and len(episodes) > 1:
        for i, ep in enumerate(episodes):      # half the list away: another task in every format
            ep.extra["rgb_from"] = episodes[(i + max(len(episodes) // 2, 1)) % len(episodes)].spec
    for ep in episodes:
        if rgb_lag_frames:
            ep.extra["rgb_lag_frames"] = int(rgb_lag_frames)
        if reverse_rgb:
            ep.extra["reverse_rgb"] = True
    return episodes


def control_video(ep, world: World, times, size: tuple[int, int], seed: int):
    """The frames the episode's camera stores: its own world at `times` (None: the video frame times), or
    in a control corpus that world K frames earlier (`extra["rgb_lag_frames"]`), played backwards
    (`extra["reverse_rgb"]`), or another episode's world (`extra["rgb_from"]`), each frame at a random
    moment of that episode."""
    other = ep.extra.get("rgb_from")
    times = ep.spec.frame_times() if times is None else np.asarray(times, np.float64)
    if other is None:
        if ep.extra.get("reverse_rgb"):
            times = times[0] + times[-1] - times
        return world.render_frames(times - ep.extra.get("rgb_lag_frames", 0) / ep.spec.fps, size)
    rng = np.random.default_rng(stable_hash(seed, "mispair-rgb", ep.fmt, ep.name) & 0x7FFFFFFF)
    return World(other).render_frames(rng.uniform(0.0, other.duration_s, len(times)), size)
