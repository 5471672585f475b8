"""Broken control corpora (htdata/synthetic/controls.py): the video is wrong in exactly the way named."""

import numpy as np
import pytest

from htdata.errors import ArgumentError
from htdata.synthetic.controls import control_video
from htdata.synthetic.corpus import CorpusConfig, PlannedEpisode, corpus_identity, plan_corpus
from htdata.synthetic.world import EpisodeSpec, World

SIZE = (64, 48)


def _episode(**extra):
    spec = EpisodeSpec("power_grasp", "Home", seed=3, n_frames=20, timing="late").validate()
    return PlannedEpisode("native", spec, "rec", dict(extra)), World(spec)


def test_a_lagged_video_shows_the_moment_k_frames_earlier_and_a_reversed_one_plays_backwards():
    ep, world = _episode()
    times = ep.spec.frame_times()
    own = np.stack(list(control_video(ep, world, None, SIZE, 0)))
    np.testing.assert_array_equal(own, np.stack(list(world.render_frames(times, SIZE))))
    lagged, _ = _episode(rgb_lag_frames=6)
    late = np.stack(list(control_video(lagged, world, None, SIZE, 0)))
    np.testing.assert_array_equal(late[6:], own[:-6])                    # frame i = the own frame i - 6
    assert not np.array_equal(late, own)
    backwards, _ = _episode(reverse_rgb=True)
    np.testing.assert_array_equal(np.stack(list(control_video(backwards, world, None, SIZE, 0))), own[::-1])


def test_the_control_is_in_the_corpus_identity_and_only_one_at_a_time(tmp_path):
    plain = corpus_identity(CorpusConfig(out=tmp_path).validate())
    lagged = corpus_identity(CorpusConfig(out=tmp_path, rgb_lag_frames=6).validate())
    assert lagged == {**plain, "rgb_lag_frames": 6} and "world" in plain    # never reused for the plain corpus
    assert all(ep.extra.get("reverse_rgb") for ep in plan_corpus(CorpusConfig(out=tmp_path, reverse_rgb=True)))
    with pytest.raises(ArgumentError, match="one broken control"):
        CorpusConfig(out=tmp_path, rgb_lag_frames=3, reverse_rgb=True).validate()
    with pytest.raises(ArgumentError, match="rgb_lag_frames"):
        CorpusConfig(out=tmp_path, rgb_lag_frames=-1).validate()
