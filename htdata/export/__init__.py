"""Exports: a committed version in another ecosystem's format, read-only on the dataset.

    lerobot.py        `htdata export lerobot`: a LeRobot v3.0 dataset (parquet rows + H.264 video)
    lerobot_plan.py   what the export will write, decided before any byte is: features, parts, each row's frame
    lerobot_out.py    where OUT may go: `--force` replaces only a previous export
    lerobot_meta.py   its meta/ files (info, tasks, episodes, htdata's layouts, masks and split)
    lerobot_stats.py  per-feature statistics gathered in the export's one pass (meta/stats.json)
    lerobot_window.py `--tactile-window K`: the glove rows between two frames, at the glove's own rate
    videoencode.py    H.264 mp4 with explicit timestamps (PyAV)

May import: reading, inspection, the store, the glove model, the format and the base modules.
Never curation, ingest or the commands.
"""
