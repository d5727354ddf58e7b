"""The ``percver`` command. Each sub-command lives in its own module and registers itself here."""

from __future__ import annotations

import argparse
import sys

from percver.errors import PercverError

# (module, function) pairs; each function takes the argparse sub-parsers object and adds one command
# whose parser has ``func`` set via ``set_defaults(func=...)``; ``func(args) -> int`` is the exit code.
COMMANDS = [
    ("percver.commands.demo", "register"),
    ("percver.commands.validate", "register"),
    ("percver.commands.cases", "register"),
    ("percver.commands.verify", "register"),
    ("percver.commands.import_verisig", "register"),
    ("percver.commands.selftest", "register"),
]


def version() -> str:
    """The installed distribution's version (the wheel's metadata), else the core's (a source tree on PYTHONPATH)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("percver")
    except PackageNotFoundError:
        from percver import _core

        return _core.__version__


def build_parser() -> argparse.ArgumentParser:
    import importlib

    parser = argparse.ArgumentParser(
        prog="percver",
        description="Data-driven modeling and formal verification of perception-based autonomous systems.",
    )
    parser.add_argument("--version", action="version", version=f"percver {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module, function in COMMANDS:
        getattr(importlib.import_module(module), function)(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except PercverError as error:
        print(f"percver {args.command}: error: {error}", file=sys.stderr)
        return 1
    except FileNotFoundError as error:
        print(f"percver {args.command}: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
