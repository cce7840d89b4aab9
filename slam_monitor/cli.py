"""``seesys`` subcommands of the device part: tracking and vocabulary (``tracking_commands``) and the RTS
monitor (``monitor_commands``), session export (``session_commands``) and the camera check
(``camera_commands``)."""

from __future__ import annotations

import argparse

from slam_monitor import camera_commands, monitor_commands, session_commands, tracking_commands


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add the device commands to the ``seesys`` command line."""
    tracking_commands.register(subparsers)
    monitor_commands.register(subparsers)
    session_commands.register(subparsers)
    camera_commands.register(subparsers)
    return {}
