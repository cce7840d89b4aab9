"""``seesys study calibrate-motion``: thresholds for the ``motion`` condition from pilot sessions."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def calibrate_motion_command(args: argparse.Namespace) -> int:
    from advisory.config import load_advisory_config
    from seesys.io.logfiles import write_json_atomically
    from study.motion_calibration import calibrate_motion

    result = calibrate_motion(args.pilot, load_advisory_config(), args.latency_s)
    shares = ", ".join(
        f"N>={k}: seesys {a:.3f} motion {b:.3f}"
        for k, (a, b) in enumerate(zip(result.seesys_tick_shares, result.motion_tick_shares), start=1)
    )
    print(f"{len(result.sessions)} seesys sessions of {args.pilot}; ticks {shares}")
    print(
        f"buffers that warned: seesys {result.seesys_warning_share:.3f}, motion replayed "
        f"{result.motion_warning_share:.3f} (ratio {result.warning_ratio:.3f})"
    )
    print("configs/advisory.toml [motion]:")
    print(f"thresholds_m_s = {json.dumps(result.thresholds_m_s).replace('Infinity', 'inf')}")
    if args.out is not None:
        write_json_atomically(args.out, result.record())
        print(f"record: {args.out}")
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "calibrate-motion",
        help="thresholds for the motion condition that pulse as often as seesys did in pilot sessions",
        description="Reads the finished seesys sessions of a pilot study folder (people, or `seesys study simulate` "
        "with operators drawn from another seed than the study's), measures how often SEESys gave N >= k "
        "pulses, and sets the motion condition's thresholds to the quantiles of the motion statistic that give "
        "the same shares. Prints the thresholds for configs/advisory.toml and how well the replayed motion rule "
        "matches.",
    )
    p.add_argument("pilot", type=Path, help="the pilot study folder")
    p.add_argument(
        "--latency-s",
        type=float,
        default=0.0,
        metavar="S",
        help="the time from a frame to its features at the advisory (a simulated study's estimate_latency_s)",
    )
    p.add_argument("--out", type=Path, metavar="FILE", help="write the calibration's record (JSON) here")
    p.set_defaults(func=calibrate_motion_command)
