"""``seesys run``: a thin wrapper over :mod:`seesys_app.run`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from advisory.conditions import LIVE_CONDITIONS, Condition
from seesys.io.arguments import positive_int

# A degraded run ended as its source did, but with seconds in which the advisory knew nothing.
EXIT_STATUS = {"completed": 0, "degraded": 3, "interrupted": 130}


def final_line(status: str, summary: dict, folder: Path) -> str:
    """The one line ``seesys run`` ends with: the outcome, frames, estimates and their latency (when there were
    any), buffers, audio and the session folder; a failed run's line is its error."""
    if status == "failed":
        return f"seesys: error: {summary['error']} (session {folder})"
    latency = summary["end_to_end_ms"]
    estimates = (
        f"{summary['estimates']} estimates (end to end p50 {latency['p50']:.0f} / p95 {latency['p95']:.0f} ms)"
        if latency["p50"] is not None
        else "no estimates"
    )
    information = summary["information"]
    without = ""
    if information["seconds_without"] > 0:
        reasons = ", ".join(f"{reason} {seconds:.1f} s" for reason, seconds in information["by_reason"].items())
        without = f" ({information['seconds_without']:.1f} s without information: {reasons})"
    return (
        f"{status}{without}: {summary['frames']} frames, {estimates}, {summary['buffers']} advisory buffers; "
        f"audio {summary['audio']}; session {folder}"
    )


def _run(args: argparse.Namespace) -> int:
    from seesys_app.run import App, RunOptions, plan_run

    options = RunOptions(
        source=args.source,
        condition=Condition(args.condition),
        out=args.out,
        local=args.local,
        estimator=args.estimator,
        model=args.model,
        wav=args.wav,
        mode=args.mode,
        pace=args.pace,
        max_frames=args.max_frames,
    )
    result = App(plan_run(options)).run()
    print(
        final_line(result.status, result.summary, result.folder),
        file=sys.stderr if result.status == "failed" else sys.stdout,
    )
    return EXIT_STATUS.get(result.status, 1)


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add ``seesys run`` to the command line."""
    p = subparsers.add_parser(
        "run",
        help="the handheld advisory as one app: device, estimator and advisory, supervised, with a live view",
        description="Start the device (ORB-SLAM3 + RTS monitor), the estimator (local, or a remote service's "
        "estimates) and the advisory; supervise them, show a live view, and write one session folder "
        "with every part's logs and summary.json. Ctrl-C stops everything cleanly. Defaults: "
        "configs/app.toml.",
    )
    p.add_argument(
        "--source",
        required=True,
        metavar="KIND:PATH",
        help="frame source, as for `seesys track` (tum:DIR, realsense:, rsbag:FILE, ...)",
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--local", action="store_true", help="run the estimator service on this machine")
    where.add_argument(
        "--estimator",
        metavar="HOST:PORT",
        help="a remote estimator service's estimates endpoint (it must reach this device's feature "
        "stream: features_endpoint of configs/network.toml)",
    )
    p.add_argument(
        "--condition",
        choices=LIVE_CONDITIONS,
        required=True,
        help="what the advisory plays: seesys (Equation 2 on the estimates), rotation, motion (the rate-matched "
        "motion rule), none (silent)",
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="session folder to create (new or empty)")
    p.add_argument(
        "--wav",
        action="store_true",
        help="do not play the audio, only write it to the WAV in the session folder (needs jackd; the WAV "
        "is written in any case)",
    )
    p.add_argument("--model", type=Path, help="the local estimator's ONNX model (default: configs/service.toml)")
    p.add_argument("--mode", choices=["rgbd", "mono"], help="SLAM mode (default: configs/app.toml)")
    pacing = p.add_mutually_exclusive_group()
    pacing.add_argument(
        "--pace",
        dest="pace",
        action="store_true",
        default=None,
        help="play a recording at camera rate, as a live camera delivers it, never waiting for "
        "ORB-SLAM3's mapping (default: configs/app.toml)",
    )
    pacing.add_argument("--no-pace", dest="pace", action="store_false", help="feed frames as fast as SLAM takes them")
    p.add_argument("--max-frames", type=positive_int, metavar="N", help="stop the device after N frames")
    p.set_defaults(func=_run)
    return {}
