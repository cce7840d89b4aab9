"""``seesys study ...``: the user-study kit's commands."""

from __future__ import annotations

import argparse

from study import commands_calibration, commands_mocap, commands_sessions


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add ``seesys study`` to the ``seesys`` command line."""
    parser = subparsers.add_parser("study", help="user studies: sessions, motion capture, calibration, metrics")
    commands = parser.add_subparsers(dest="study_command", metavar="COMMAND", required=True)
    commands_sessions.register(commands)
    commands_mocap.register(commands)
    commands_calibration.register(commands)
    return {"study": commands}
