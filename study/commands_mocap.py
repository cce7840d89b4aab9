"""``seesys study metrics|calibrate|mocap``: metrics of two trajectories, the calibration of a session's motion
capture, live mocap logging and file import."""

from __future__ import annotations

import argparse
import json
import signal
from pathlib import Path

import numpy as np

from seesys.core.camera_scale import ScaleCheckError, ScaleFit, describe, window_scales
from seesys.core.trajectory import Poses
from seesys.io.camera_check import load_scale_settings
from seesys.io.processes import stop_on_signals
from seesys.io.trajectory_files import read_tum, write_tum
from study.config import MetricsConfig, load_study_config
from study.metrics import format_metrics, read_frame_log, tracking_metrics


def metrics_command(args: argparse.Namespace) -> int:
    cfg = load_study_config().metrics
    frames = read_frame_log(args.frames) if args.frames else None
    slam, mocap = read_tum(args.slam), read_tum(args.mocap)
    result = tracking_metrics(slam, mocap, args.mono, cfg, frames)
    scale = None if args.mono else camera_scale(slam, mocap, cfg)
    if args.json:
        print(json.dumps({**result.as_dict(), "camera_scale": _scale_record(scale)}, indent=2))
        return 0
    print(format_metrics(result))
    if scale is not None:
        print(f"camera scale against the mocap: {scale if isinstance(scale, str) else describe(scale)}")
    return 0


def _scale_record(scale: ScaleFit | str | None) -> dict | None:
    if scale is None or isinstance(scale, str):
        return None if scale is None else {"not_measured": scale}
    return {
        "scale": scale.scale,
        "p10": scale.spread[0],
        "p90": scale.spread[1],
        "windows": scale.windows,
        "depth_scale_error": scale.depth_scale_error,
    }


def camera_scale(slam: Poses, mocap: Poses, cfg: MetricsConfig) -> ScaleFit | str:
    """RGB-D: the SLAM trajectory's scale against the mocap (a depth scale error no estimate shows), on the tracked
    poses, a stretch ending where poses are ``stretch_gap_s`` apart; why not, when it cannot be measured."""
    try:
        return window_scales(
            slam,
            np.ones(len(slam), bool),
            mocap,
            cfg.association_max_dt_s,
            load_scale_settings(),
            max_gap_s=cfg.stretch_gap_s,
        )
    except ScaleCheckError as e:
        return f"not measured ({e})"


def calibrate_command(args: argparse.Namespace) -> int:
    from study.mocap.calibrate import calibrate_session, format_calibration

    cfg = load_study_config()
    result = calibrate_session(
        args.session,
        cfg.calibration,
        args.body or cfg.mocap.body,
        mocap=args.mocap,
        marker_camera_from=args.hand_eye_from,
        monocular=args.mono,
        overwrite=args.overwrite,
        offset_guess_s=args.offset_guess,
    )
    print(format_calibration(result))
    print(f"wrote {args.session / 'groundtruth.tum'} and {args.session / 'calibration.json'}")
    return 0


def mocap_log_command(args: argparse.Namespace) -> int:
    from study.mocap.logger import log_mocap

    cfg = load_study_config().mocap
    # SIGTERM (the study runner stopping a session) ends the loop cleanly, like Ctrl-C.
    with stop_on_signals(signal.SIGTERM) as stop:
        try:
            stats = log_mocap(cfg, args.out, stop, args.duration)
        except KeyboardInterrupt:
            return 130
    print(f"mocap: {stats.poses} poses of '{stats.body}' ({stats.missing} frames without it) in {args.out}")
    return 0


def mocap_import_command(args: argparse.Namespace) -> int:
    from study.mocap.importers import read_mocap

    poses = read_mocap(args.file, args.body or load_study_config().mocap.body)
    write_tum(args.out, poses)
    print(f"{args.out}: {len(poses)} poses")
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "metrics",
        help="tracking error (evo RPE), completeness, losses of two TUM trajectories",
        description="Tracking error (evo RPE, translation part, delta and association from "
        "configs/study.toml, SE(3) alignment or Sim(3) with --mono), completeness, "
        "tracking losses and time on task.",
    )
    p.add_argument("--slam", required=True, type=Path, metavar="EST.tum", help="SLAM trajectory (TUM)")
    p.add_argument("--mocap", required=True, type=Path, metavar="REF.tum", help="reference trajectory (TUM)")
    p.add_argument(
        "--frames",
        type=Path,
        metavar="frames.csv",
        help="the session's frame log: completeness counted on camera frames",
    )
    p.add_argument("--mono", action="store_true", help="monocular SLAM: Sim(3) alignment")
    p.add_argument(
        "--json", action="store_true", help="print JSON (keys rpe_mean_m, rpe_rmse_m, pairs, completeness, ...)"
    )
    p.set_defaults(func=metrics_command)

    p = commands.add_parser("calibrate", help="clock offset and hand-eye of a session's mocap; writes groundtruth.tum")
    p.add_argument("session", type=Path, metavar="SESSION")
    p.add_argument(
        "--mocap", type=Path, metavar="FILE", help="mocap file (TUM or Vicon CSV; default SESSION/mocap.tum)"
    )
    p.add_argument("--body", help="rigid body in a Vicon CSV (default configs/study.toml)")
    p.add_argument(
        "--hand-eye-from",
        type=Path,
        metavar="calibration.json",
        help="reuse the marker-to-camera transform of an earlier (RGB-D) calibration",
    )
    p.add_argument("--mono", action="store_true", help="monocular trajectory (needs --hand-eye-from)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing groundtruth.tum")
    p.add_argument(
        "--offset-guess",
        type=float,
        metavar="S",
        help="search the clock offset around S seconds (default: 0 when the recordings overlap in time, "
        "else the difference of their start times)",
    )
    p.set_defaults(func=calibrate_command)

    mocap = commands.add_parser("mocap", help="live motion-capture logging and file import")
    sub = mocap.add_subparsers(dest="mocap_command", metavar="COMMAND", required=True)
    p = sub.add_parser("log", help="log the configured rigid body to DIR/mocap.tum (stamped on receipt)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until SIGTERM/Ctrl-C)")
    p.set_defaults(func=mocap_log_command)
    p = sub.add_parser("import", help="convert a Vicon CSV export (or TUM file) of one body to TUM")
    p.add_argument("file", type=Path)
    p.add_argument("--body", help="subject or segment name (default configs/study.toml)")
    p.add_argument("--out", required=True, type=Path, metavar="OUT.tum")
    p.set_defaults(func=mocap_import_command)
