"""Source adapters: one per raw recording format (docs/INGEST.md "Adapters").

`ADAPTERS` maps the adapter name used in pipeline TOML files to its class;
`get_adapter(name)` returns a fresh instance.
"""

from __future__ import annotations

from htdata.errors import ArgumentError
from htdata.source.adapters.base import Adapter, EpisodeRef, EpisodeStreams
from htdata.source.adapters.native import NativeAdapter
from htdata.source.adapters.opentouch import OpenTouchAdapter
from htdata.source.adapters.touchanything import TouchAnythingAdapter

ADAPTERS: dict[str, type] = {
    "opentouch": OpenTouchAdapter,
    "touchanything": TouchAnythingAdapter,
    "native": NativeAdapter,
}


def get_adapter(name: str) -> Adapter:
    try:
        return ADAPTERS[name]()
    except KeyError:
        raise ArgumentError(f"unknown adapter {name!r}; known: {sorted(ADAPTERS)}") from None


__all__ = ["ADAPTERS", "Adapter", "EpisodeRef", "EpisodeStreams", "get_adapter"]
