"""Inspection: read-only views of a committed dataset.

    episodestats.py  per-episode statistics from the raw rows and maps
    stats.py         `htdata stats`: the cached per-episode statistics, summaries by task / source
    statscache.py    one cache entry read no further than its shape (a stranger's stats/ file)
    scalehint.py     a `scale` per glove layout from the p99.9 of its pressed values
    healthmap.py     the taxel-health PNG
    outline.py       region outlines drawn over every map picture
    preview.py       `htdata preview`: a contact sheet of frames
    view.py          `htdata view`: one episode streamed to Rerun (RGB, maps, curves on one timeline)
    viewlayout.py    what `htdata view` shows: entities, static layers, the blueprint
    card.py          `htdata card`: the dataset card (HTML)
    cardplots.py     the card's charts (bars, ticked histograms, region heat maps)

May import: reading, the store, the glove model, the format and the base modules.
Never curation, ingest or the commands.
"""
