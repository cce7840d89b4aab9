"""Command-line wrappers for the device part (see slam_monitor/cli.py)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add these commands to the ``seesys`` command line."""
