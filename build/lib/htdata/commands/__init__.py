"""The `htdata` subcommands: one module per command, each `configure_parser(parser)` + `run(args) -> int`.

Commands parse arguments, call the core modules and print; core modules
(ingest, split, validate, ...) neither parse arguments nor print.
`htdata/cli.py` holds the table of commands.
"""
