"""``seesys session export-bag``: a session folder for ROS tools (rviz, Foxglove, ``ros2 bag play``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from seesys.io.core_settings import load_label_config
from seesys.io.session_bag import export_session_bag, load_export_settings


def _export_bag(args: argparse.Namespace) -> int:
    counts = export_session_bag(args.session, args.out, load_export_settings(), load_label_config().delta_frames)
    print(f"{args.out}: " + ", ".join(f"{topic} {count}" for topic, count in counts.items()))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``seesys session`` to the command line."""
    session = subparsers.add_parser("session", help="work with a recorded session folder")
    sub = session.add_subparsers(dest="session_command", metavar="SUBCOMMAND")
    p = sub.add_parser(
        "export-bag",
        help="write a session's poses, tracking states and estimates as a ROS 2 bag "
        "(topics and storage: configs/export.toml)",
    )
    p.add_argument("session", type=Path, metavar="SESSION", help="session folder (seesys track / monitor run / run)")
    p.add_argument("--out", type=Path, required=True, help="the ROS 2 bag folder to create (must not exist)")
    p.set_defaults(func=_export_bag)
