"""Episodes named on a command line: the one did-you-mean line every command gives for a miss."""

from __future__ import annotations

import pytest

from htdata.curate import edit
from htdata.errors import ArgumentError
from htdata.store.episodeids import NoSuchEpisode, no_such_episode, resolve_episodes

IDS = ["ep_1", "ep_17", "ot-kitchen-demo_08", "ot-kitchen-demo_09"]


def test_a_miss_names_the_count_and_the_near_ids():
    err = no_such_episode("ot-kitchen-demo_8", IDS)
    assert isinstance(err, ArgumentError)
    assert str(err) == ("no episode matches 'ot-kitchen-demo_8' (4 episodes); did you mean: ot-kitchen-demo_08, "
                        "ot-kitchen-demo_09")
    assert str(no_such_episode("zzz", IDS[:1], "episodes in main/test")) == \
        "no episode matches 'zzz' (1 episodes in main/test)"      # nothing near: no hint


def test_ids_and_globs_resolve_in_dataset_order_and_curate_uses_the_resolver():
    assert resolve_episodes(IDS, ["ot-*", "ep_1"]) == ["ep_1", "ot-kitchen-demo_08", "ot-kitchen-demo_09"]
    with pytest.raises(NoSuchEpisode, match="did you mean: ep_17, ep_1"):
        resolve_episodes(IDS, ["ep_7"])
    assert edit.resolve_episodes is resolve_episodes
