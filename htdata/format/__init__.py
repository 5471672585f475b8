"""The on-disk format: what a writer and a reader must agree on.

    canvas.py     the canvas side and the hand names
    table.py      file names of a dataset, the member table and the index dtype
    codec.py      the member codecs' registry (MEMBER_CODECS) and JPEG RGB, npy raw rows, PNG masks, JSON
    tactilecodec.py  the tactile value rule and the EXR map codec (half / float pixels)
    exrzip.py     the ZIP EXR map writer, built byte by byte (OpenEXR's file layout, ISA-L's deflate)
    imageheader.py JPEG and EXR sizes read from the header bytes, checked before a decoder allocates them
    shardio.py    tar shards: sample keys, the shard writer and member-range reads
    mapstorage.py MapStorage: maps stored, or rendered from raw rows by the readers ([tactile] maps, codec.tactile.maps)
    tactilesettings.py  a pipeline's [tactile] section: EXR compression, raster mode, raw rows, maps stored or not

May import: htdata's base modules only. Everything else builds on it.

`from htdata.format import NAME` keeps working, with a DeprecationWarning, for the
names of the format table (table.py) until htdata/_moved.py's REMOVED_IN; new code
imports `htdata.format.table`.

Imports inside functions: `__getattr__` imports htdata._moved (which imports table.py)
only when an old name is asked for, so importing htdata.format.codec does not import
the table (which imports the codecs).
"""


def __getattr__(name: str):
    from htdata._moved import moved_name  # lazy: see the docstring

    return moved_name(__name__, name)
