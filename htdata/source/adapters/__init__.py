"""Source adapters: one per raw recording format (docs/INGEST.md "Adapters").

`ADAPTERS` maps the adapter name used in pipeline TOML files to its class;
`get_adapter(name)` returns a fresh instance.

    base.py           the contract: EpisodeRef, EpisodeStreams, Adapter, FileDiscovery
    discovery.py      per-file discovery (one bad file never hides the rest), episode ids, fingerprints
    sourcetree.py     which files an adapter may read (regular files inside the source root)
    params.py         declared [adapter.params]: AdapterParam, param_values, check_declared_params
    streamchecks.py   an opened episode's checks: grid vs layout, length note, episode-video iterator
    opentouch.py      OpenTouch-style: one HDF5 per scene, clips under `data/demo_NN`
    touchanything.py  TouchAnything-style: one folder per episode
    native.py         htdata-native: folders holding recording.json (docs/NATIVE_FORMAT.md)
    hdf5safe.py       HDF5 a stranger wrote, opened safely (sizes checked, no byte of another file)
    npzrows.py        forward row reads from one .npy member of an .npz, without loading the array
    video.py          packet timestamps (no decode) and streaming RGB decode
    mp4header.py      an MP4's declared sizes (samples, SPS picture) read from its boxes before FFmpeg opens it

May import: what htdata.source may (the base modules, the format, the glove model) and
htdata.source's own modules.
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


def nothing_found(name: str, root, params: dict | None = None) -> str:
    """Why adapter `name` found no recording under `root`, and which adapter's files are there instead
    (a folder of another format is the most common cause: the pipeline was mistyped)."""
    adapter = get_adapter(name)
    text = f"no {adapter.recording_files} under {root}, so the {name!r} adapter found no recording"
    others = [other for other in ADAPTERS if other != name and _holds(other, root)]
    if others:
        text += "; it holds " + " and ".join(f"{get_adapter(o).recording_files}: --pipeline {o}" for o in others)
    return text


def _holds(name: str, root) -> bool:
    try:
        return bool(get_adapter(name).discovery_files(root, {}))
    except (OSError, ValueError):   # a tree this adapter refuses to walk holds none of its files
        return False


def get_adapter(name: str) -> Adapter:
    try:
        return ADAPTERS[name]()
    except KeyError:
        raise ArgumentError(f"unknown adapter {name!r}; known: {sorted(ADAPTERS)}") from None


__all__ = ["ADAPTERS", "Adapter", "EpisodeRef", "EpisodeStreams", "get_adapter", "nothing_found"]
