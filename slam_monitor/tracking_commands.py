"""``seesys track`` and ``seesys vocab train``: thin wrappers over the device worker, supervisor and trainer.

Other commands that run a device session (``seesys monitor run``) reuse :func:`add_session_arguments`,
:func:`session_options_from_args` and :func:`run_session_with_progress`, adding their observers.
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from seesys.io.arguments import positive_int
from seesys.io.config import replace_fields
from slam_monitor.device_worker import FrameTracked, ObserverSpec, SessionOptions, SessionStarted
from slam_monitor.orbslam_settings import SlamMode, load_slam_config
from slam_monitor.sources import load_camera_config, open_source, parse_source_spec, source_kinds_help
from slam_monitor.supervisor import run_supervised_session
from slam_monitor.trajectory_metrics import SessionSummary, summarize_session

CM_PER_M = 100.0


def add_session_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of every command that runs a device session."""
    parser.add_argument("--source", required=True, metavar="KIND:PATH", help=f"frame source: {source_kinds_help()}")
    parser.add_argument(
        "--mode",
        choices=[m.value for m in SlamMode],
        default=SlamMode.RGBD.value,
        help="ORB-SLAM3 sensor mode (default rgbd)",
    )
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="session folder to write")
    parser.add_argument("--max-frames", type=positive_int, metavar="N", help="stop after N frames")
    parser.add_argument(
        "--settings",
        type=Path,
        metavar="YAML",
        help="use this ORB-SLAM3 settings file instead of generating one from configs/slam.toml",
    )
    parser.add_argument(
        "--vocabulary",
        type=Path,
        metavar="FILE",
        help="ORB vocabulary (default: $PYORBSLAM3_VOCAB, else configs/slam.toml)",
    )
    pacing = parser.add_mutually_exclusive_group()
    pacing.add_argument(
        "--pace",
        dest="pace",
        action="store_true",
        default=None,
        help="feed frames no faster than their timestamps (default: configs/slam.toml [pacing])",
    )
    pacing.add_argument("--no-pace", dest="pace", action="store_false", help="feed frames as fast as SLAM takes them")
    pacing.add_argument(
        "--real-time",
        dest="pace",
        action="store_const",
        const="real-time",
        help="feed frames at their timestamps and never wait for ORB-SLAM3's mapping, as a live camera "
        "delivers them (a recording standing in for a camera: what the estimator and the "
        "advisory see is then real time)",
    )


def session_options_from_args(args: argparse.Namespace, observers: Sequence[ObserverSpec] = ()) -> SessionOptions:
    """:class:`SessionOptions` from the arguments of :func:`add_session_arguments`, plus observers."""
    parse_source_spec(args.source)  # an unknown kind is reported before a process is started
    real_time = args.pace == "real-time"
    return SessionOptions(
        source=args.source,
        mode=SlamMode(args.mode),
        out_dir=args.out,
        max_frames=args.max_frames,
        settings_file=args.settings,
        vocabulary=args.vocabulary,
        pace=True if real_time else args.pace,
        wait_for_mapping=False if real_time else None,
        observers=tuple(observers),
    )


def run_session_with_progress(options: SessionOptions, console: Console | None = None) -> SessionSummary:
    """Run the session in a supervised worker with a progress bar, then summarise the session folder."""
    console = console or Console(stderr=True)
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("tracked {task.fields[tracked]}"),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    ) as bar:
        task = bar.add_task("starting ORB-SLAM3", total=None, tracked=0)
        tracked = 0

        def show(event: object) -> None:
            nonlocal tracked
            if isinstance(event, SessionStarted):
                bar.update(task, description=f"tracking {options.mode.value}", total=event.frame_count)
            elif isinstance(event, FrameTracked):
                tracked += event.tracked
                bar.update(task, advance=1, tracked=tracked)

        run_supervised_session(options, progress=show)
    return summarize_session(options.out_dir, options.mode)


def format_summary(summary: SessionSummary) -> str:
    lines = [
        f"frames:  {summary.frames}",
        f"tracked: {summary.frames_tracked} ({summary.tracked_percent:.1f} %)",
    ]
    if summary.ate is not None:
        lines.append(
            f"ATE:     {summary.ate.rmse_m * CM_PER_M:.2f} cm RMSE ({summary.ate.alignment} alignment, "
            f"{summary.ate.pairs} poses, scale {summary.ate.scale:.3f})"
        )
    else:
        lines.append("ATE:     n/a (no ground truth, or too few tracked poses to align)")
    return "\n".join(lines)


def track_command(args: argparse.Namespace) -> int:
    options = session_options_from_args(args)
    summary = run_session_with_progress(options)
    print(format_summary(summary))
    print(f"session: {options.out_dir}")
    return 0


def vocab_train_command(args: argparse.Namespace) -> int:
    from slam_monitor import vocabulary

    slam_config = load_slam_config()
    training = slam_config.vocabulary_training
    if args.branching or args.levels:
        training = replace_fields(
            training, branching=args.branching or training.branching, levels=args.levels or training.levels
        )
    orb = slam_config.orb
    extractor = vocabulary.orb_extractor(orb.features, orb.scale_factor, orb.levels, orb.ini_fast_threshold)
    console = Console(stderr=True)
    with (
        open_source(parse_source_spec(args.source), load_camera_config(), with_depth=False) as source,
        Progress(
            TextColumn("extracting ORB features"),
            BarColumn(),
            MofNCompleteColumn(),
            console=console,
            transient=True,
            disable=not console.is_terminal,
        ) as bar,
    ):
        total = min(filter(None, (source.frame_count, args.max_frames)), default=None)
        frames = bar.track(itertools.islice(source.frames(), args.max_frames), total=total)
        descriptors = vocabulary.extract_descriptors(frames, extractor, training.frame_step)
    with console.status(f"clustering {sum(len(d) for d in descriptors)} descriptors"):
        trained = vocabulary.train_vocabulary(descriptors, training)
    vocabulary.write_vocabulary(args.out, trained)
    header = vocabulary.validate_vocabulary(args.out)
    print(
        f"vocabulary: {args.out} (k={header.branching}, L={header.levels}, {header.words} words, "
        f"{header.nodes} nodes, trained on {len(descriptors)} images)"
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``seesys track`` and ``seesys vocab train``."""
    track = subparsers.add_parser(
        "track",
        help="run ORB-SLAM3 on a frame source and write a session folder",
        description="Run ORB-SLAM3 on a camera, recording or dataset; write "
        "trajectory.tum, frames.csv and session.json; print a summary.",
    )
    add_session_arguments(track)
    track.set_defaults(func=track_command)

    vocab = subparsers.add_parser("vocab", help="ORB vocabularies for ORB-SLAM3")
    vocab_commands = vocab.add_subparsers(dest="vocab_command", metavar="COMMAND")
    train = vocab_commands.add_parser(
        "train",
        help="train a DBoW2 ORB vocabulary from a frame source",
        description="Hierarchical k-majority clustering of ORB descriptors with "
        "IDF weights, written in ORB-SLAM's DBoW2 text format.",
    )
    train.add_argument(
        "--source", required=True, metavar="KIND:PATH", help=f"frames to train on: {source_kinds_help()}"
    )
    train.add_argument("--out", required=True, type=Path, metavar="FILE", help="vocabulary file to write")
    train.add_argument("--max-frames", type=positive_int, metavar="N", help="use at most N frames")
    train.add_argument(
        "--branching", type=positive_int, metavar="K", help="children per node (default configs/slam.toml)"
    )
    train.add_argument("--levels", type=positive_int, metavar="L", help="tree depth (default configs/slam.toml)")
    train.set_defaults(func=vocab_train_command)
