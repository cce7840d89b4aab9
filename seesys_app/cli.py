"""The ``seesys`` command: one subcommand group per part of the system.

Each part (``slam_monitor``, ``synth``, ``estimator``, ``advisory``, ``study``, ``analysis``, and the app,
``seesys_app``) exposes ``register(subparsers)`` in its ``cli`` module, which returns the command groups it made by
name; a part above may add commands to a lower part's group (``GROUP_EXTENSIONS``). A registered command sets
``func`` to a callable taking the parsed arguments and returning an exit status. The CLI layer only parses and
reports: the work is in the libraries. The parts are imported by name, when the parser is built, so that importing
this module loads none of them; a command line that names a group imports only the parts that make that group
(``COMMAND_GROUPS``), because every process that the app, the study runner and the service start is a ``seesys``
command, and importing every part (SciPy, pandas, Matplotlib, the dataset builder) cost each of them about 3 s of
start-up on a 2-core machine.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from seesys import __version__
from seesys.core.errors import SeesysError

# Commands that a part adds to a lower part's group: (group, module, function taking the group's subcommands).
# `synth diversity` reads rendered frames through the device's image statistics, which the renderer never imports;
# `study simulate` runs the estimator in-process, which the study's own commands never import.
GROUP_EXTENSIONS = (
    ("synth", "estimator.cli", "register_synth_commands"),
    ("study", "seesys_app.simulate.cli", "register"),
)


# The part that makes each command group (its ``register`` adds the group's top-level command). A first word not
# listed here (a typo, ``--help``) builds the whole parser, so that argparse names the choices.
COMMAND_GROUPS = {
    "track": "slam_monitor.cli",
    "vocab": "slam_monitor.cli",
    "monitor": "slam_monitor.cli",
    "session": "slam_monitor.cli",
    "camera": "slam_monitor.cli",
    "synth": "synth.cli",
    "dataset": "estimator.cli",
    "estimator": "estimator.cli",
    "advisory": "advisory.cli",
    "study": "study.cli",
    "analyze": "analysis.cli",
    "run": "seesys_app.run_cli",
}
PART_MODULES = tuple(dict.fromkeys(COMMAND_GROUPS.values()))


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``seesys`` parser; given the group a command line names (its first word), only that group's parts."""
    parser = argparse.ArgumentParser(
        prog="seesys",
        description="SEESys: online pose error estimation for visual SLAM, with an audio error advisory.",
    )
    parser.add_argument("--version", action="version", version=f"seesys {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    part = COMMAND_GROUPS.get(command or "")
    for name in PART_MODULES:
        if part is None or part == name:
            groups.update(importlib.import_module(name).register(subparsers))
    for group, name, function in GROUP_EXTENSIONS:
        if group in groups and (part is None or group == command):
            getattr(importlib.import_module(name), function)(groups[group])
    return parser


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    parser = build_parser(words[0] if words else None)
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
