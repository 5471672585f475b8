"""htdata: full-hand tactile + egocentric RGB dataset toolkit.

The tree follows the data path (docs/DESIGN.md):

    source/    read a recording (adapters), pair its clocks (sync, lag), RGB preprocessing
    glove/     layouts, normalisation, calibration, rasterisation, taxel health
    format/    the on-disk format: member table, codecs, tar shards
    ingest/    recordings -> a committed version (plan, units, commit)
    store/     versions, manifests, parts, snapshots, the writer lock, remote storage
    read/      DatasetReader and the torch datasets
    inspect/   stats, health maps, previews, the dataset card
    export/    a version in LeRobot's format
    curate/    split, rm/trim, merge, gc, renormalise: new versions from old
    validate/  `htdata validate`
    sample/    the synthetic sample corpus
    benchmarks/, commands/, cli.py: `htdata bench` and the command line

The front door:

    import htdata
    ds = htdata.open("data/dataset")           # DatasetReader of the current version
    ds.meta                                    # its records: episodes, splits, coverage (DatasetMetadata)
    ds = htdata.open("data/dataset", version=3)

Imports inside functions: `open` imports the reader when it is called, so that
`import htdata` (which every command line run does first) stays cheap.
"""

from htdata import _moved

__version__ = "0.1.0"

_moved.install()


def open(path, version=None):  # noqa: A001 (the front door's name, like LeRobot's one class)
    """Open a committed dataset (local path or fsspec URL) at one of its versions.

    Args:
        path: the dataset root: a local path or an fsspec URL (file://, memory://, s3://...).
        version: the version to open (`htdata log` lists them); None: the current one.

    Returns:
        `htdata.read.torchviews.Dataset`: a `DatasetReader` whose `.meta` holds the version's
        records (DatasetMetadata: episodes, splits, coverage, ...) and whose `.torch` builds the
        torch datasets of the same version (`ds.torch.frames(split="main", part="train")`).

    Raises:
        FileNotFoundError: `path` holds no committed dataset.
        htdata.errors.ArgumentError: `version` is not one of its versions (also a FileNotFoundError).
    """
    # Lazy: `import htdata` must stay cheap (the CLI imports it before parsing arguments).
    from htdata.read.torchviews import Dataset

    return Dataset(path, version=version)
