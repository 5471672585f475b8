"""`htdata` command line: one subcommand per module, imported lazily.

Each command module exposes `configure_parser(parser)` and `run(args) -> int`.
Keeping the table here (and the options in each module) avoids one giant
argparse block while `htdata --help` still lists everything.

Imports inside functions: a command's module (and so its dependencies: torch,
cv2, h5py ...) is imported only when that command runs; `--version` reads
htdata's version the same way.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys

from htdata.errors import AlreadyCommitted, HtdataError

# name -> (module, one-line help). Order is the order of the data path.
COMMANDS: dict[str, tuple[str, str]] = {
    "sample": ("htdata.commands.sample", "generate a small raw corpus in all three source formats"),
    "ingest": ("htdata.commands.ingest", "read raw recordings and write a validated, sharded dataset"),
    "split": ("htdata.commands.split", "task-level OOD hold-out + 9:1 episode split (or --list-tasks)"),
    "validate": ("htdata.commands.validate", "prove a dataset is sound (structure, content, time, splits)"),
    "stats": ("htdata.commands.stats", "frames, contact, value quantiles, regions and taxel health; --health OUT.png"),
    "card": ("htdata.commands.card", "a self-contained HTML dataset card (+ Markdown) with stats and plots"),
    "log": ("htdata.commands.log", "list the versions of a dataset (every write makes one)"),
    "diff": ("htdata.commands.diff", "episodes added / removed / changed between two versions"),
    "rm": ("htdata.commands.rm", "remove episodes (ids or globs) as a new version; --dry-run"),
    "trim": ("htdata.commands.trim", "keep frames A:B of an episode as a new version; --dry-run"),
    "renormalise": ("htdata.commands.renormalise",
                    "new maps from the stored raw glove rows under a new calibration, as a new version"),
    "merge": ("htdata.commands.merge", "merge two datasets into a new one without re-encoding"),
    "gc": ("htdata.commands.gc", "delete old versions and shards no kept version lists; --dry-run"),
    "repair": ("htdata.commands.repair", "rewrite dataset.json from the newest version file; --dry-run"),
    "upgrade": ("htdata.commands.upgrade", "store the current version in today's format, as a new version; --dry-run"),
    "preview": ("htdata.commands.preview", "render a contact sheet: RGB beside left/right tactile maps"),
    "view": ("htdata.commands.view", "scrub one episode in Rerun: RGB, both hands' maps and contact curves in time"),
    "pipelines": ("htdata.commands.pipelines", "list the shipped ingest pipelines, or print one to copy and edit"),
    "layouts": ("htdata.commands.layouts", "list, check and render hand layouts (register a glove)"),
    "publish": ("htdata.commands.publish", "upload a dataset to an fsspec URL (s3://, gs://, memory://), manifest last"),
    "export": ("htdata.commands.export", "write a dataset version in another format: `export lerobot` (LeRobot v3.0)"),
    "bench": ("htdata.commands.bench", "run the benchmarks and write bench/results.json + report"),
}


# `htdata --help` lists the commands by what they are for.
GROUPS: dict[str, tuple[str, ...]] = {
    "build": ("sample", "ingest", "renormalise", "pipelines", "layouts"),
    "curate": ("split", "rm", "trim", "merge", "gc", "repair", "upgrade"),
    "inspect": ("log", "diff", "stats", "validate", "preview", "view", "card"),
    "share": ("publish", "export"),
    "measure": ("bench",),
}
EXAMPLES = """\
examples:
  htdata sample data/raw --scale small                      # a small raw corpus to try things on
  htdata ingest --pipeline opentouch data/raw/opentouch data/dataset
  htdata split data/dataset --ood-task palm_push --name main
  htdata stats data/dataset --brief
  htdata export lerobot data/dataset data/lerobot

Run `htdata COMMAND --help` for a command's options, defaults and examples."""


def grouped_commands() -> str:
    lines = []
    for group, names in GROUPS.items():
        lines.append(f"{group}:")
        lines += [f"  {name:<12} {COMMANDS[name][1]}" for name in names]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="htdata", usage="htdata [--version] COMMAND ...",
        description="Build, curate, inspect and share full-hand tactile + egocentric RGB datasets.\n\n"
        + grouped_commands(),
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from htdata import __version__

    parser.add_argument("--version", action="version", version=f"htdata {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", help=argparse.SUPPRESS)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, description=help_text)
        p.set_defaults(_module=module)
        # Options are added lazily only for the chosen command (fast --help).
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if not argv or argv[0] not in COMMANDS:
        args = parser.parse_args(argv)  # prints help / errors for unknown commands
        parser.print_help()
        return 0 if not argv else 2
    name = argv[0]
    module = importlib.import_module(COMMANDS[name][0])
    sub = argparse.ArgumentParser(prog=f"htdata {name}", description=COMMANDS[name][1] + ".",
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    module.configure_parser(sub)
    args = sub.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except BrokenPipeError:   # `htdata log | head -1`: the reader has what it wanted; stop quietly
        _silence_stdout()
        return 141            # what a shell reports for a writer ended by SIGPIPE (128 + 13)
    except KeyboardInterrupt:   # Ctrl-C: one line, no traceback; every write commits whole or not at all
        how = getattr(module, "INTERRUPTED", "run the command again: a version is committed whole or not at all")
        print(f"\nhtdata {name}: interrupted (Ctrl-C); {how}", file=sys.stderr)
        return 130
    except AlreadyCommitted as exc:   # a re-run of a write killed after its commit: the change is there
        print(f"htdata {name}: {exc}")
        return 0
    except HtdataError as exc:   # a user-caused error no command caught itself: its one line, no traceback
        print(f"htdata {name}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno == errno.EROFS:   # a read-only dataset: one line, whichever write met it first
            print(f"htdata {name}: error: {exc.filename or 'the dataset'} is on a read-only file system; nothing "
                  f"was written", file=sys.stderr)
            return 2
        if exc.errno not in _NO_SPACE:
            raise
        # every writer writes temp + rename and commits last: a failed write leaves the current version as it was
        print(f"htdata {name}: error: {exc.strerror} writing {exc.filename or 'a file'}; nothing was committed "
              f"(the current version is unchanged): free space and run the command again", file=sys.stderr)
        return 2


_NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's flush at exit does not meet the closed pipe again
    (the way the Python docs give for SIGPIPE; signals stay as they are, so a write still finishes whole)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):   # stdout has no file descriptor (captured): nothing will flush to a pipe
        pass


if __name__ == "__main__":
    sys.exit(main())
