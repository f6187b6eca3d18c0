"""The ``metraw`` command line.

Each subcommand lives in its own module ``metraw.cli.<name>`` exposing
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``.
Errors caused by the input (``MetrawError``, unreadable files) print one line on stderr (``metraw
check-folder``: one line per problem it found) and exit with status 2; nothing half-written is left (outputs are written atomically). With
``METRAW_USAGE_LOG`` set (the workflow sets it), a command that succeeds ends with one line of the
CPU, wall time and peak memory it used (``metraw.progress.usage_line``).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

from metraw import __version__, allocator, progress
from metraw.errors import MetrawError

#: Subcommand modules in the order shown by ``metraw --help``.
COMMANDS = ("info", "check-folder", "ingest", "calibrate", "scenes", "encode", "decode", "verify", "emulate",
            "pretrain", "train", "evaluate", "predict", "compress", "aggregate", "check", "normalise")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="metraw", description="Metrologically correct raw images: "
                                     "ingest, calibrate, emulate, compress, segment, specify.")
    parser.add_argument("--version", action="version", version=f"metraw {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module_name = f"metraw.cli.{name.replace('-', '_')}"
        if importlib.util.find_spec(module_name) is None:
            continue
        importlib.import_module(module_name).register(sub)
    return parser


def one_line(text: str) -> str:
    """``text`` as one printable line: control characters and line breaks (e.g. a decoder's message that
    echoes damaged bytes) become spaces, runs of whitespace one space."""
    return " ".join("".join(ch if ch.isprintable() else " " for ch in text).split())


def main(argv: list[str] | None = None) -> int:
    allocator.tune()  # before the commands' large arrays (their worker processes inherit it)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    progress.start_command()
    try:
        rc = int(args.func(args) or 0)
        if rc == 0 and progress.usage_wanted():
            print(progress.usage_line(args.command), file=sys.stderr, flush=True)
        return rc
    except MetrawError as exc:
        print(f"metraw {args.command}: error: {one_line(str(exc))}", file=sys.stderr)
        for line in getattr(exc, "details", ()):  # a check that lists every problem it found, one a line
            print(f"  {one_line(line)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"metraw {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
