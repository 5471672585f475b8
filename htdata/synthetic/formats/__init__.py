"""Writers for raw recordings in the three source layouts.

Used by the synthetic sample corpus (`htdata sample`) and by the adapter
tests. Each writer reproduces its source's on-disk layout exactly (same
keys, dtypes and quirks), so the adapters are tested against the real
shape of the data:

- OpenTouch-style: one HDF5 per scene, clips under `data/demo_NN`, JPEGs
  stored with R and B swapped, inverted pressure units (3072 = no load).
- TouchAnything-style: one folder per episode with H.264 videos,
  `pressure_grids.npz` (21x21, NaN = no sensor, right grid mirrored),
  `jq_pressure.json` (JSON Lines, epoch seconds) and side-data JSON Lines.
- htdata-native: the project's own format (docs/NATIVE_FORMAT.md).

Frames are taken from iterables and written one at a time, so long
episodes stream to disk. One module per source (`opentouch`,
`touchanything`, `native`, mirroring htdata/source/adapters/), shared encoding in
`media`; the names below are the writers' public API.

May import: what htdata.synthetic may; a writer mirrors its adapter's format and never imports
the adapter that reads it (the tests pair them).
"""

from htdata.synthetic.formats.media import write_h264
from htdata.synthetic.formats.native import (
                                          NATIVE_FORMAT,
                                          NATIVE_FORMAT_VERSION,
                                          NativeHand,
                                          NativeRecording,
                                          write_native_recording,
)
from htdata.synthetic.formats.opentouch import (
                                          OPENTOUCH_ANNOTATION_COLUMNS,
                                          OPENTOUCH_LABEL_DTYPE,
                                          OpenTouchClip,
                                          write_opentouch_annotations,
                                          write_opentouch_scene,
)
from htdata.synthetic.formats.touchanything import (
                                          TA_FPS,
                                          TA_GRID,
                                          TA_SPLIT_KEYS,
                                          TA_VIDEO_SIZE,
                                          TouchAnythingEpisode,
                                          write_touchanything_episode,
                                          write_touchanything_split,
)

__all__ = [
    "NATIVE_FORMAT", "NATIVE_FORMAT_VERSION", "NativeHand", "NativeRecording", "write_native_recording",
    "OPENTOUCH_ANNOTATION_COLUMNS", "OPENTOUCH_LABEL_DTYPE", "OpenTouchClip", "write_opentouch_annotations",
    "write_opentouch_scene",
    "TA_FPS", "TA_GRID", "TA_SPLIT_KEYS", "TA_VIDEO_SIZE", "TouchAnythingEpisode", "write_touchanything_episode",
    "write_touchanything_split",
    "write_h264",
]
