"""The ``seesys`` command: one subcommand group per part of the system.

Each part (``slam_monitor``, ``estimator``, ``advisory``, ``study``, ``analysis``, and the app, ``seesys.app``) exposes
``register(subparsers)`` in its ``cli`` module; a registered command sets ``func`` to a callable taking the
parsed arguments and returning an exit status. The CLI layer only parses and reports: the work is in the
libraries.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from seesys import __version__
from seesys.core.errors import SeesysError

PART_MODULES = (
    "slam_monitor.cli",
    "estimator.cli",
    "advisory.cli",
    "study.cli",
    "analysis.cli",
    "seesys.app.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="seesys",
        description="SEESys: online pose error estimation for visual SLAM, with an audio error advisory.",
    )
    parser.add_argument("--version", action="version", version=f"seesys {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in PART_MODULES:
        module = importlib.import_module(name)
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        return int(args.func(args) or 0)
    except SeesysError as e:
        print(f"seesys: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("seesys: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
