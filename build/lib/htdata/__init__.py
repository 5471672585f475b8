"""htdata: full-hand tactile + egocentric RGB dataset toolkit.

Data path: adapters (read a source) -> sync (pair clocks) -> normalise (glove
units to [0,1]) -> rasterise (taxels to the canonical 224x224 map) -> codec
(EXR/JPEG) -> shards + index -> reader / torchdata -> handtouch trainer.
"""

__version__ = "0.1.0"


def open(path, version=None):
    """The dataset at `path` (a directory or fsspec URL), current version or `version`: a DatasetReader.

        import htdata
        ds = htdata.open("data/dataset")
        sample = ds.decoded(0)        # {"rgb": (224,224,3) uint8, "tactile": {hand: (224,224)}, "raw": ..., "meta": ...}
    """
    from htdata.reader import DatasetReader   # lazy: `import htdata` stays light

    return DatasetReader(path, version=version)
