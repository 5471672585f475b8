"""`htdata pipelines list|show NAME`: the ingest pipelines that ship with htdata."""

from __future__ import annotations

import argparse
import sys

from htdata.ingest.pipeline import resolve_pipeline_path, shipped_pipelines

EPILOG = """\
A pipeline is a TOML file that says how to read one source format (adapter), pair its clocks
(sync), normalise the glove values and encode the samples. `htdata ingest --pipeline NAME`
takes a shipped name or a path to your own .toml; to change a setting, either pass
`--set key=value` to ingest or copy the shipped file and edit it.

Examples:
  htdata pipelines list
  htdata pipelines show opentouch > my_opentouch.toml   # then: htdata ingest --pipeline my_opentouch.toml ...
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="names and one-line descriptions of the shipped pipelines")
    show = sub.add_parser("show", help="print a shipped pipeline's TOML (to copy and edit)")
    show.add_argument("name", help="a name from `htdata pipelines list`")


def run(args: argparse.Namespace) -> int:
    import tomllib


    names = shipped_pipelines()
    if args.action == "list":
        for name in names:
            path = resolve_pipeline_path(name)
            description = tomllib.loads(path.read_text()).get("description", "")
            print(f"{name:<15} {description}")
        print("\nhtdata pipelines show NAME prints one; htdata ingest --pipeline NAME SRC OUT uses it.")
        return 0
    if args.name not in names:
        print(f"htdata pipelines: error: no shipped pipeline {args.name!r} (shipped: {', '.join(names)})",
              file=sys.stderr)
        return 2
    sys.stdout.write(resolve_pipeline_path(args.name).read_text())
    return 0
