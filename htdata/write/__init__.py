"""What both writers of new versions share: `ingest` (recordings -> a version) and `curate`
(a version -> a new version) sit side by side above this layer, and neither imports the other.

    newversion.py  `NewVersion`, the one owner of a new version's transaction: the writer lock, the
                parent, unit numbers (an interrupted write's leftovers cleared), re-packed parts, the
                commit (`store.snapshot.commit_parts`), or this write's units cleaned up on failure
    repack.py   copy samples of committed shards into new shards, byte for byte (an append's
                reused episodes; rm, trim, merge; renormalise's re-encoded maps)

May import: reading (a repack reads committed samples), the store, the glove model, the format
and the base modules. Never ingest, curate, validate, the benchmarks or the commands.
"""
