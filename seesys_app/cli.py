"""The ``seesys`` command: one subcommand group per part of the system.

Each part (``slam_monitor``, ``synth``, ``estimator``, ``advisory``, ``study``, ``analysis``, and the app,
``seesys_app``) exposes ``register(subparsers)`` in its ``cli`` module, which returns the command groups it made by
name; a part above may add commands to a lower part's group (``GROUP_EXTENSIONS``). A registered command sets
``func`` to a callable taking the parsed arguments and returning an exit status. The CLI layer only parses and
reports: the work is in the libraries. The parts are imported by name, when the parser is built, so that importing
this module loads none of them.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from seesys import __version__
from seesys.core.errors import SeesysError

PART_MODULES = (
    "slam_monitor.cli",
    "synth.cli",
    "estimator.cli",
    "advisory.cli",
    "study.cli",
    "analysis.cli",
    "seesys_app.run_cli",
)

# Commands that a part adds to a lower part's group: (group, module, function taking the group's subcommands).
# `synth diversity` reads rendered frames through the device's image statistics, which the renderer never imports;
# `study simulate` runs the estimator in-process, which the study's own commands never import.
GROUP_EXTENSIONS = (
    ("synth", "estimator.cli", "register_synth_commands"),
    ("study", "seesys_app.simulate.cli", "register"),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="seesys",
        description="SEESys: online pose error estimation for visual SLAM, with an audio error advisory.",
    )
    parser.add_argument("--version", action="version", version=f"seesys {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    for name in PART_MODULES:
        groups.update(importlib.import_module(name).register(subparsers))
    for group, name, function in GROUP_EXTENSIONS:
        getattr(importlib.import_module(name), function)(groups[group])
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
