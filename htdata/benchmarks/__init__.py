"""Benchmarks behind `htdata bench`: each returns rows (dicts); suite.py runs them side by side, report.py renders REPORT.md.

    suite.py       runs the sections side by side (and the `htdata.bench_sections` entry points)
    report.py      REPORT.md from the sections' rows
    tables.py      markdown tables of benchmark rows: the one formatter every section uses
    machine.py     the machine a benchmark ran on: CPUs, RAM, load, library versions
    timing.py      small timing helpers shared by the sections
    sources.py     real frames for the benchmarks: sample-corpus episodes read through the adapters
    ingest.py      ingest throughput per adapter against the bare decode+resize+encode bound; memory vs length
    scaling.py     ingest worker scaling (1 -> N workers, N = the machine's cores)
    driver.py      the ingest driver's serial work per frame at two corpus sizes; HT-Bench (10M frames) on 64 cores
    append.py      appending one episode to datasets of N and 10N episodes: wall time and bytes written
    revisions.py   the same ingest under another revision of htdata, side by side
    loader.py      read paths of a committed dataset vs the bare decode bound
    dataloader.py  TactileFrameDataset through a torch DataLoader at 1 and N workers
    htbenchsize.py "size": a dataset at HT-Bench's size by replication; every metadata command's time, memory, bytes
    index.py       index.npy at scale: open time and memory of a 1M / 10M-row index
    codecs.py      tactile map codecs on real maps, against each glove's quantisation step
    maplayouts.py  how one EXR map member is written, measured side by side on real maps
    maps.py        maps stored or rendered from raw rows: bytes against read speed; glove-only ingest, stored vs raw
    mapcost.py     where a glove-only ingest's time goes when it stores its maps, and what would reach 0.8x raw
    raw.py         what keeping every raw glove row costs, what rendering maps from them gains
    raster.py      rasterisation mode x glove layout: render speed vs taxel round-trip error
    rawglove.py    "raw-count glove": baselines and noise floors scored against the generator's truth
    rawglovecells.py  "raw-count glove", moving cells: the moving-cell rule against the generator's truth
    realclips.py   raw-count glove clips measured by their counts: a real-glove folder (given explicitly) or the sample glove
    realglove.py   "real glove": the raw-count defaults against the folder README's measures and targets (+ stats, trim)
    realglovecells.py  moving cells and suggested blocks on real glove recordings (a folder given explicitly)
    realglovev2.py  measures version 2 (rest from the glove, not the clip) and the gloves derived from the clips
    lag.py         the tactile-video lag estimator: error against known lags, cost per episode minute
    rgb.py         RGB: JPEG quality vs bytes vs PSNR, resize method vs time vs error
    stats.py       `htdata stats` speed against the loader's tactile-only decode rate
    validation.py  `htdata validate --deep` throughput at 1 and 2 workers
    export.py      `htdata export lerobot` speed and size against htdata's own shards
    view.py        `htdata view --save` seconds and peak memory against episode length

torch: `dataloader.py` imports it at module level, `rgb.py` (`resize_rows`) and `machine.py`
(`machine_info`, where it may be missing) inside a function; `loader.py` and `maps.py` reach it
through htdata/read/torchdata.py. So `htdata bench` needs the [bench] extra; `htdata bench --help`
(which loads no section) does not.

May import: every layer below it (it measures them all: the format up to validate and the
synthetic corpus). Never the commands; another package's section plugs in through the entry
point group `htdata.bench_sections`, never imported by name (htdata never imports handtouch).
"""
