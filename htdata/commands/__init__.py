"""The `htdata` subcommands: one module per command, each `configure_parser(parser)` + `run(args) -> int`.

Commands parse arguments, call the core modules and print; core modules
(ingest, split, validate, ...) neither parse arguments nor print.
`htdata/cli.py` holds the table of commands.

    ingest.py       `htdata ingest`: raw recordings -> a committed dataset
    sample.py       `htdata sample`: the synthetic raw corpus
    pipelines.py    `htdata pipelines list|show`: the shipped ingest pipelines
    layouts.py      `htdata layouts`: list, check, suggest and render glove layouts
    validate.py     `htdata validate`: the verdict and the JSON report
    stats.py        `htdata stats`: what a dataset holds (+ a health map)
    preview.py      `htdata preview`: a contact sheet of one episode
    view.py         `htdata view`: one episode in Rerun (RGB, maps, curves on one timeline)
    card.py         `htdata card`: a self-contained dataset card
    log.py          `htdata log`: the versions of a dataset
    diff.py         `htdata diff`: episodes added, removed and changed between two versions
    split.py        `htdata split`: a new version holding a split
    rm.py           `htdata rm`: a new version without some episodes
    trim.py         `htdata trim`: keep a frame range of one episode
    merge.py        `htdata merge`: one dataset from two, shards never re-encoded
    renormalise.py  `htdata renormalise`: new normalisation from the stored raw rows
    gc.py           `htdata gc`: delete old versions after their retention window
    repair.py       `htdata repair`: dataset.json back in line with the version files
    upgrade.py      `htdata upgrade`: the current version stored again in today's format
    publish.py      `htdata publish`: upload a committed dataset to an fsspec URL
    export.py       `htdata export lerobot`: a LeRobot v3.0 dataset from one version
    bench.py        `htdata bench`: every benchmark side by side
    outputs.py      where a command's output goes: the one rule for output paths
    version_arg.py  a version on the command line: `3` or `v3`

May import: every layer below it (a command parses its arguments and calls a core module that
does the work, then prints). Only htdata/cli.py sits above, loading a command when it runs.
"""
