"""The store: a dataset's files on disk, its versions and their lifecycle primitives.

    fsutil.py    the sha256 of a stored file, local or at a URL (the atomic writes are htdata/fileio.py)
    storage.py   local paths and fsspec URLs behind one small API (readers); this machine's cache folder
    confine.py   the paths a dataset's records name stay inside its root
    lock.py      the one-writer lock
    writable.py  the folders writers write in are real folders of the dataset, never symlinks out of it
    versions.py  version files: names, paths, write a version, change records
    manifest.py  load / parse a version's manifest, episode records and index (any format); layout files
    indexfile.py an index .npy read safely (its header against its size, an older dtype converted)
    parts.py     a version as parts (one per work unit) and their assembly into one index
    segments.py  format 4: a version's records as shared immutable segments, so a write costs what it changes
    splitfiles.py split documents of a version: read, count, carry to a child version
    splitrule.py  the split rule: which part each episode goes to, and the split document it makes
    snapshot.py  open a version as a snapshot; commit parts as a new version
    episodeids.py episodes named by ids or globs; the one did-you-mean error of a miss
    history.py   log and diff of versions
    gcrecord.py  gc tombstones: what `htdata gc` leaves for the readers it may outlive (`VersionCollected`)
    repair.py    `htdata repair`: dataset.json back in line with the version files
    remote.py    publish a committed dataset to a URL (verified, manifest last); cache a remote index
    publishplan.py  what a publish uploads: the current version pinned as a reader pins it, and its files
    destination.py  where a publish may write: never into its dataset, over another dataset or someone's files

May import: htdata's base modules, htdata.format and htdata.glove (calibration records).
Never ingest, reading, curation, inspection or the commands.
"""
