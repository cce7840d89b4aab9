"""``seesys`` subcommands of the study part."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add this part's commands to the ``seesys`` command line (none yet)."""
