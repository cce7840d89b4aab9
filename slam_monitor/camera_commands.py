"""``seesys camera check SESSION...``: the camera's metric scale against ground truth, and what its calibration
should say (:mod:`seesys.core.camera_scale`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from seesys.core.camera_scale import ScaleFit, depth_scale_error, describe
from seesys.io.camera_check import SessionScale, load_scale_settings, session_scale
from seesys.io.core_settings import load_label_config
from slam_monitor.sources.settings import FileSourceDefaults, folder_calibration, load_camera_config


def _folder_depth_factor(source: str, defaults: FileSourceDefaults) -> tuple[Path, float] | None:
    """The depth factor a folder source's calibration (or the camera config's default) gave a session recorded
    from ``source`` (KIND:PATH), when it was a dataset folder."""
    kind, _, path = source.partition(":")
    if kind != "tum" or not Path(path).is_dir():
        return None
    return Path(path), folder_calibration(Path(path), defaults).depth_units_per_metre


def _check(args: argparse.Namespace) -> int:
    settings = load_scale_settings()
    association = load_label_config().association_max_dt_s
    checked: list[SessionScale] = [session_scale(folder, settings, association) for folder in args.sessions]
    for one in checked:
        print(f"{one.folder}: {describe(one.fit)}")
    applied = {one.applied_correction for one in checked}
    pooled = ScaleFit.pooled([one.fit for one in checked])
    if len(checked) > 1:
        print(f"all {len(checked)} sessions: {describe(pooled)}")
    if len(applied) > 1:
        print(
            "the sessions were recorded with different depth corrections "
            f"({', '.join(f'{a:g}' for a in sorted(applied))}): check them one at a time"
        )
        return 1
    correction = pooled.correction(applied.pop())
    print(
        "\nFor this camera, in camera.toml (the source multiplies every depth by it):\n"
        f"[scale]\ndepth_correction = {correction:.4f}"
    )
    defaults = load_camera_config().files
    for one in checked:
        folder = _folder_depth_factor(one.source, defaults)
        if folder is not None:
            print(
                f"or in {folder[0] / 'calibration.yaml'}: depth_factor: {one.fit.depth_factor(folder[1]):.2f} "
                f"(was {folder[1]:g})"
            )
    error = depth_scale_error(correction)
    if abs(error) > settings.warn_above:
        print(
            f"warning: a depth scale error of {error:+.1%}, above the {settings.warn_above:.0%} "
            "the app tolerates silently; the app warns at start while camera.toml records it"
        )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``seesys camera`` to the command line."""
    camera = subparsers.add_parser("camera", help="check a camera against ground truth")
    sub = camera.add_subparsers(dest="camera_command", metavar="SUBCOMMAND")
    p = sub.add_parser(
        "check",
        help="the camera's metric scale from RGB-D sessions with ground truth, and the "
        "depth correction its config should say (settings: [scale] of camera.toml)",
        description="Fits the Sim(3) scale of each session's SLAM trajectory onto its ground truth "
        "on windows of tracked frames, and prints the scale, its spread, the depth "
        "scale error it means and the camera.toml lines that correct it. A depth scale "
        "error is invisible to the estimator: only ground truth shows it.",
    )
    p.add_argument(
        "sessions",
        type=Path,
        nargs="+",
        metavar="SESSION",
        help="RGB-D session folders with groundtruth.tum (seesys track / monitor run / run on a source "
        "with ground truth)",
    )
    p.set_defaults(func=_check)
