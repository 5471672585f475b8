"""Source adapters: one per raw recording format (docs/INGEST.md "Adapters").

`ADAPTERS` maps the adapter name used in pipeline TOML files to its class;
`get_adapter(name)` returns a fresh instance.

    base.py          the contract: EpisodeRef, EpisodeStreams, Adapter, FileDiscovery
    discovery.py     per-file discovery (one bad file never hides the rest), episode ids, fingerprints
    sourcetree.py    which files an adapter may read (regular files inside the source root)
    params.py        declared [adapter.params]: AdapterParam, param_values, check_declared_params
    streamchecks.py  an opened episode's checks: grid vs layout, length note, episode-video iterator
    npzrows.py       row reads from an .npz member without loading the archive
    hdf5safe.py      HDF5 opened so that no byte of another file is read
    video.py         video probing (pts) and decoding
    opentouch.py, touchanything.py, native.py   the three adapters
"""

from __future__ import annotations

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
        raise ValueError(f"unknown adapter {name!r}; known: {sorted(ADAPTERS)}") from None


__all__ = ["ADAPTERS", "Adapter", "EpisodeRef", "EpisodeStreams", "get_adapter"]
