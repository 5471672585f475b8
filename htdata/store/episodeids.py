"""Episodes named on a command line: exact ids or shell globs, and the one error a miss gives.

Every command that takes episode ids (`rm`, `trim`, `renormalise --episode`, `view --episode`)
answers a typo the same way: one line naming what matched nothing, how many episodes there
are, and the near matches (difflib), e.g.
``no episode matches 'ep_7' (12 episodes); did you mean: ep_1, ep_17``.
"""

from __future__ import annotations

import difflib
import fnmatch

from htdata.errors import ArgumentError


class NoSuchEpisode(ArgumentError):
    """An episode id or pattern matched nothing."""


def no_such_episode(name: str, ids: list[str], among: str = "episodes") -> NoSuchEpisode:
    """The error for `name` matching none of `ids`, with its near matches (`among`: what `ids` are)."""
    near = difflib.get_close_matches(name, ids, n=5, cutoff=0.6)
    hint = f"; did you mean: {', '.join(near)}" if near else ""
    return NoSuchEpisode(f"no episode matches {name!r} ({len(ids)} {among}){hint}")


def resolve_episodes(ids: list[str], patterns: list[str]) -> list[str]:
    """Episode ids named by exact ids or shell globs (*, ?, [..]), in dataset order.

    Raises:
        NoSuchEpisode: a pattern that matches no id (the first such, with its near matches).
    """
    chosen: set[str] = set()
    known = set(ids)
    for pattern in patterns:
        if any(c in pattern for c in "*?["):
            hits = fnmatch.filter(ids, pattern)
        else:
            hits = [pattern] if pattern in known else []
        if not hits:
            raise no_such_episode(pattern, ids)
        chosen.update(hits)
    return [e for e in ids if e in chosen]
