"""What both writers of new versions share: `ingest` (recordings -> a version) and `curate`
(a version -> a new version) sit side by side above this layer, and neither imports the other.

    repack.py   copy samples of committed shards into new shards, byte for byte (an append's
                reused episodes; rm, trim, merge; renormalise's re-encoded maps)

May import: reading (a repack reads committed samples), the store, the glove model, the format
and the base modules. Never ingest, curate, validate, the benchmarks or the commands.
"""
