"""Reading a committed dataset: the last step before the trainer.

    metadata.py    DatasetMetadata: one version's records (manifest, episodes, index, splits, coverage,
                   region maps; split -> sample indices), never a shard
    reader.py      DatasetReader: one version's samples (random access, windows, streaming; local or URL),
                   built on its DatasetMetadata (`reader.meta`)
    samplerow.py   where a sample lies in its shard: its index row (SampleRow), its members' spans
    onerror.py     a streaming reader's `on_error=` (raise / warn and skip / skip a sample it cannot read)
    rawstream.py   an episode's raw glove rows at full rate, from the shards; MapServing (the loaders' maps_from)
    torchdata.py   torch datasets of frames and windows (maps stored or rendered from raw rows)
    torchitems.py  what a torch item carries: the members asked for, per-layout constants per item or once
    itemoptions.py ItemOptions: what the torch datasets share (which samples, version, what an item carries)
    torchglove.py  torch dataset of raw glove rows at the glove's own rate
    keys.py        the keys of the items the torch datasets yield
    torchviews.py  `Dataset` (what htdata.open returns): a reader whose `.torch` builds the torch datasets

May import: the store, the format, the glove model and the base modules. torch only in
torchdata, torchitems and torchglove (an optional extra).
"""
