"""``seesys monitor run``: a device session (``seesys track``) with the RTS monitor observing every frame and,
optionally, streaming its features to the estimator."""

from __future__ import annotations

import argparse
import json

from seesys.core.errors import SeesysError
from slam_monitor.device_worker import ObserverSpec
from slam_monitor.estimates import summary_line
from slam_monitor.monitor import MONITOR_STATS_JSON
from slam_monitor.tracking_commands import (
    add_session_arguments,
    format_summary,
    run_session_with_progress,
    session_options_from_args,
)

MONITOR_FACTORY = "slam_monitor.monitor:create_observer"
ESTIMATES_FACTORY = "slam_monitor.estimates:create_observer"


class MonitorFailed(SeesysError):
    """The RTS monitor stopped during a session (tracking went on)."""


def format_monitor_stats(stats: dict) -> str:
    lines = [
        f"monitor: {stats['frames_processed']} frames processed, {stats['frames_dropped']} dropped, "
        f"{stats['psd_matrices']} PSD matrices, {stats['monitor_ms_median']:.2f} ms/frame median "
        f"({stats['monitor_ms_p90']:.2f} p90)"
    ]
    if stats["stream"] is not None:
        lines.append(
            f"stream:  {stats['stream']['messages']} messages published, {stats['stream_kbit_per_s']:.1f} "
            f"kbit/s at the camera rate (receivers count what they miss)"
        )
    return "\n".join(lines)


def monitor_run_command(args: argparse.Namespace) -> int:
    observers = [ObserverSpec(MONITOR_FACTORY, {"stream": args.stream or args.estimates, "device_id": args.device_id})]
    if args.estimates:
        observers.append(ObserverSpec(ESTIMATES_FACTORY, {"device_id": args.device_id}))
    options = session_options_from_args(args, observers=observers)
    summary = run_session_with_progress(options)
    stats = json.loads((options.out_dir / MONITOR_STATS_JSON).read_text())
    print(format_summary(summary))
    print(format_monitor_stats(stats))
    if args.estimates:
        print(summary_line(options.out_dir))
    print(f"session: {options.out_dir}")
    if stats["error"] is not None:
        raise MonitorFailed(
            f"the RTS monitor stopped at {stats['error']}; tracking went on, its logs up to there "
            f"are in {options.out_dir} (traceback in {MONITOR_STATS_JSON})"
        )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``seesys monitor run``."""
    monitor = subparsers.add_parser("monitor", help="the RTS monitor (runtime status + point spatial distribution)")
    commands = monitor.add_subparsers(dest="monitor_command", metavar="COMMAND")
    run = commands.add_parser(
        "run",
        help="track with ORB-SLAM3 and run the RTS monitor beside it",
        description="Run ORB-SLAM3 on a frame source (as `seesys track`) with the RTS monitor: writes rts.csv, "
        "psd/ and monitor_stats.json into the session folder and, with --stream, publishes one "
        "feature message per frame on features_endpoint of configs/network.toml.",
    )
    add_session_arguments(run)
    run.add_argument(
        "--stream",
        action="store_true",
        help="publish the features over ZeroMQ (the device keeps going when nobody listens)",
    )
    run.add_argument(
        "--estimates",
        action="store_true",
        help="also receive this device's estimates from the estimator service and log them with their "
        "latency in estimates.csv (implies --stream)",
    )
    run.add_argument("--device-id", metavar="ID", help="device id on the stream (default configs/monitor.toml)")
    run.set_defaults(func=monitor_run_command)
