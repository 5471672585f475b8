"""htdata: full-hand tactile + egocentric RGB dataset toolkit.

The tree follows the data path (docs/DESIGN.md):

    source/    read a recording (adapters), pair its clocks (sync, lag), RGB preprocessing
    glove/     layouts, normalisation, calibration, rasterisation, taxel health
    format/    the on-disk format: member table, codecs, tar shards
    store/     versions, manifests, parts, snapshots, the writer lock, remote storage
    read/      DatasetReader, its version's metadata (DatasetMetadata) and the torch datasets
    inspect/   stats, health maps, previews, the dataset card
    export/    a version in LeRobot's format
    write/     what both writers share: repack (committed samples into new shards)
    ingest/    recordings -> a committed version (pipeline, plan, units, commit)    } the two writers,
    curate/    split, rm/trim, merge, gc, renormalise: new versions from old      } side by side
    validate/  `htdata validate`
    synthetic/ the synthetic corpus (`htdata sample`)
    benchmarks/, commands/, cli.py: `htdata bench` and the command line

Root modules, below every package (every package may import them):

    errors.py     the exceptions htdata raises on purpose (ConfigError, ArgumentError, DatasetError, EpisodeError ...)
    faults.py     named crash points for the kill -9 tests of every writer
    fileio.py     crash-safe file writes (atomic_open, write_*_atomic) and sha256_stream
    resources.py  where the project's data files (schemas, layouts, pipelines) live
    settings.py   `--set [TARGET:]dotted.key=value`: the one parser of every override
    workers.py    every `--workers`: usable cores (affinity-aware), 0 = inline, the one resolver
    _moved.py     old names and keywords, importable until REMOVED_IN (deprecated, each warns)

The front door:

    import htdata
    ds = htdata.open("data/dataset")           # DatasetReader of the current version
    ds.meta                                    # its records: episodes, splits, coverage (DatasetMetadata)
    ds = htdata.open("data/dataset", version=3)

Imports inside functions: `open` imports the reader when it is called, so that
`import htdata` (which every command line run does first) stays cheap.

May import: the root modules (each of which imports only root modules); the reader only inside `open`.
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
