"""``seesys dataset build | report | splits | sample | label``: thin wrappers over :mod:`estimator.dataset`
and :mod:`seesys.core.labels`."""

from __future__ import annotations

import argparse
from pathlib import Path

from estimator.jobs import add_ray_argument
from seesys.core import session_layout
from seesys.core.errors import SeesysError
from seesys.io.config import replace_fields

# Each command imports the dataset code it runs when it runs: the service and the model commands share this part's
# command line, and the builder, the report and the labels (pandas, SciPy, Matplotlib, the renderer) would cost every
# `seesys estimator ...` process over a second of start-up.


def _names(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def _camera_names(text: str) -> list[str]:
    """Camera model names, or [] for 'preset' (each preset through its own camera model)."""
    return [] if text.strip() == "preset" else _names(text)


def _ints(text: str) -> list[int]:
    try:
        return [int(n) for n in _names(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    return width, height


def _build(args: argparse.Namespace) -> int:
    from estimator.dataset.build import DatasetBuilder, plan_from_config
    from estimator.dataset.config import load_dataset_config
    from estimator.dataset.store import WITH_SAMPLES
    from estimator.jobs import ray_executor
    from seesys.io.core_settings import load_label_config, load_window_config
    from synth.config import load_synth_config
    from synth.sequence import SequenceSpec

    config = load_dataset_config()
    synth = load_synth_config()
    if args.frames is not None and args.frames < 1:
        raise SeesysError("--frames must be at least 1")
    if args.no_keep_sessions:
        config = replace_fields(config, keep_sessions=False)
    width, height = args.size or (None, None)
    template = SequenceSpec("", "", 0, args.frames, width, height, True, args.distortion)
    plan = plan_from_config(
        config,
        synth,
        template,
        args.envs,
        args.motions,
        args.seeds,
        args.modes,
        args.trials,
        args.processes,
        args.cameras,
    )
    if args.ray is None:
        builder = DatasetBuilder(args.out, config, synth, load_label_config(), load_window_config())
        result = builder.build(plan)
    else:
        # Absolute: a task on another node does not run in this folder.
        builder = DatasetBuilder(args.out.absolute(), config, synth, load_label_config(), load_window_config())
        with ray_executor(args.ray or None) as executor:
            result = builder.build(plan, executor)
    stored = [r for r in result.runs_done if r.status in WITH_SAMPLES]
    render_rate = result.rendered_frames / result.render_seconds if result.rendered_frames else 0.0
    print(
        f"{result.sequences} sequences ({result.rendered_frames} frames rendered in {result.render_seconds:.0f} s, "
        f"{render_rate:.1f} frames/s); {len(stored)} runs stored ({sum(r.samples for r in stored)} samples), "
        f"{len(result.crashed)} crashed, "
        f"{result.runs_skipped} already done; SLAM + labelling {result.slam_seconds:.0f} s; under {args.out}"
    )
    for run in result.crashed:
        kept = f" ({run.frames} frames before it stored)" if run.frames else ""
        print(f"  crashed{kept}: {run.run}: {run.error}")
    return 0


def _report(args: argparse.Namespace) -> int:
    from estimator.dataset.config import load_dataset_config
    from estimator.dataset.report import REPORT_MD, write_report
    from seesys.core.units import MM_PER_M

    config = load_dataset_config()
    report = write_report(args.roots, config.report, config.targets, args.out)
    print((args.out / REPORT_MD).read_text(), end="")
    main = report.main_mode()
    print(f"{main.mode}: median {MM_PER_M * main.summary.median_m:.1f} mm; wrote the report under {args.out}")
    return 0


def _splits(args: argparse.Namespace) -> int:
    from estimator.dataset.config import load_dataset_config
    from estimator.dataset.splits import write_splits

    dataset = load_dataset_config()
    config = dataset.splits
    if args.heldout is not None:
        config = replace_fields(config, heldout_environments=tuple(args.heldout), heldout_environments_per_round=0)
    if args.heldout_per_round is not None:
        config = replace_fields(config, heldout_environments=(), heldout_environments_per_round=args.heldout_per_round)
    if args.heldout_cameras is not None:
        config = replace_fields(config, heldout_cameras=tuple(args.heldout_cameras))
    if args.rounds is not None:
        config = replace_fields(config, rounds=args.rounds)
    splits = write_splits(args.roots, config, args.out, dataset.lockbox, args.final)
    # Made here, the splits record their build and the configured lockbox's runs.
    assert splits.lockbox is not None and splits.build is not None
    for k, r in enumerate(splits.rounds):
        environments, cameras = splits.heldout(k)
        held = ", ".join(environments + cameras) or "none"
        print(
            f"round {k}: train {len(r.train)} runs, validation {len(r.validation)} "
            f"({', '.join(r.validation_trajectories)}), test {len(r.test)} ({', '.join(r.test_trajectories)}), "
            f"excluded {len(r.excluded)}; held out: {held}"
        )
    print(
        f"lockbox ({dataset.lockbox.environment}, {dataset.lockbox.camera_model}): {len(splits.lockbox.runs)} runs "
        f"in no round; build {splits.build.name} ({splits.build.runs} runs)"
    )
    print(f"wrote {args.out}")
    return 0


def _sample(args: argparse.Namespace) -> int:
    from estimator.dataset.config import load_dataset_config
    from estimator.dataset.sample import make_sample
    from synth.config import load_synth_config

    config = load_dataset_config().sample
    if args.env or args.motion or args.seed is not None:
        config = replace_fields(
            config,
            environment=args.env or config.environment,
            motion=args.motion or config.motion,
            seed=config.seed if args.seed is None else args.seed,
        )
    result = make_sample(config, load_synth_config(), args.out)
    print(
        f"sample: {result.frames} frames, {result.bytes / 1e6:.1f} MB in {result.folder}; check it with "
        f"`seesys track --source tum:{result.folder}` and train its vocabulary with "
        f"`seesys vocab train --source tum:{result.folder} --out FILE`"
    )
    return 0


def _label(args: argparse.Namespace) -> int:
    import numpy as np

    from seesys.core.units import MM_PER_M
    from seesys.io import session_files
    from seesys.io.core_settings import load_label_config
    from seesys.io.session_labels import label_session

    if not (args.session / session_layout.MANIFEST).is_file():
        raise SeesysError(f"{args.session} is not a session folder (no {session_layout.MANIFEST})")
    mode = session_files.read_manifest(args.session).get("mode")
    if mode not in ("rgbd", "mono"):
        raise SeesysError(f"{args.session}: session.json names no SLAM mode (rgbd or mono)")
    labels = label_session(args.session, mode == "mono", load_label_config()).to_frame()
    labelled = labels[labels.status == "labelled"]
    (labelled if args.labelled_only else labels).to_csv(args.out, index=False)
    errors_mm = labelled.error_m.to_numpy() * MM_PER_M
    summary = (
        f"median {float(np.median(errors_mm)):.1f} mm, p90 {float(np.percentile(errors_mm, 90)):.1f} mm"
        if len(labelled)
        else "no labelled frame"
    )
    print(f"{len(labelled)} of {len(labels)} frames labelled ({summary}) -> {args.out}")
    return 0


def _candidates(args: argparse.Namespace) -> int:
    import pandas as pd
    from rich.progress import track

    from estimator.dataset.candidates import candidate_frames, correlations, write_candidates_report
    from seesys.io.core_settings import load_label_config
    from slam_monitor.monitor_config import load_monitor_config

    config, labels = load_monitor_config(), load_label_config()
    frames = pd.concat([candidate_frames(s, config, labels) for s in track(args.sources, description="tracking")])
    table = correlations(frames)
    paths = write_candidates_report(frames, table, args.out)
    print(paths[-1].read_text(), end="")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def _coverage(args: argparse.Namespace) -> int:
    from estimator.dataset.covariance import (
        build_frames,
        coverage_by_set,
        model_scaled_coverage,
        read_predictions,
        write_coverage_report,
    )
    from estimator.dataset.splits import read_splits
    from seesys.io.core_settings import load_label_config

    splits = read_splits(args.splits, args.roots)
    rounds = list(range(len(splits.rounds))) if args.rounds is None else args.rounds
    frames = build_frames(args.roots, load_label_config().delta_frames)
    table = coverage_by_set(frames, splits, rounds)
    notes = [f"Data: {', '.join(str(r) for r in args.roots)}; splits {args.splits}; rounds {rounds}."]
    model_scaled = None
    if args.predictions:
        import pandas as pd

        predictions = pd.concat([read_predictions(p) for p in args.predictions], ignore_index=True)
        model_scaled = model_scaled_coverage(frames, predictions)
        notes.append(f"Estimates: {', '.join(str(p) for p in args.predictions)}.")
    path = write_coverage_report(table, args.out, notes, model_scaled)
    print(path.read_text(), end="")
    print(f"wrote {path}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``seesys dataset`` to the command line."""
    dataset = subparsers.add_parser("dataset", help="build the labelled training dataset, split it, report on it")
    sub = dataset.add_subparsers(dest="dataset_command", metavar="DATASET_COMMAND", required=True)

    p = sub.add_parser(
        "build", help="render sequences, run ORB-SLAM3 + RTS monitor on each, label, store samples (resumable)"
    )
    p.add_argument("--out", type=Path, required=True, help="dataset folder (created; an existing one is resumed)")
    p.add_argument("--envs", type=_names, help="comma-separated presets or all (default: configs/dataset.toml)")
    p.add_argument(
        "--motions",
        type=_names,
        help="comma-separated: patrol, aiming, rapid, scan, real:<name>, real, all (default: configs/dataset.toml)",
    )
    p.add_argument("--seeds", type=_ints, help="comma-separated batch seeds (default: configs/dataset.toml)")
    p.add_argument(
        "--modes", type=_names, help="comma-separated SLAM modes: rgbd, mono (default: configs/dataset.toml)"
    )
    p.add_argument("--trials", type=int, help="SLAM runs per sequence and mode (default: configs/dataset.toml)")
    p.add_argument(
        "--cameras",
        type=_camera_names,
        help="comma-separated camera models (configs/synth.toml) drawn with equal weights per sequence, or "
        "'preset' for each preset's own camera (default: [cameras] of configs/dataset.toml)",
    )
    p.add_argument("--frames", type=int, help="frames per sequence (default: configs/synth.toml duration)")
    p.add_argument("--size", type=_size, help="image size WIDTHxHEIGHT (default: configs/synth.toml camera)")
    p.add_argument("--processes", type=int, help="render processes (default: configs/synth.toml)")
    p.add_argument("--distortion", action="store_true", help="render with the configured lens distortion")
    p.add_argument("--no-keep-sessions", action="store_true", help="delete each device session folder once stored")
    add_ray_argument(p, "each render and SLAM run")
    p.set_defaults(func=_build)

    p = sub.add_parser("report", help="label distribution against the targets, feature-vs-error correlations")
    p.add_argument("roots", type=Path, nargs="+", help="dataset folders")
    p.add_argument("--out", type=Path, required=True, help="folder for label_report.md, CSV tables and PNG plots")
    p.set_defaults(func=_report)

    p = sub.add_parser(
        "candidates",
        help="the next schema's candidate channels against the label, with and without the motion statistic",
        description="Tracks each source (KIND:PATH with ground truth, e.g. tum:<a rendered folder>) once with "
        "ORB-SLAM3 (RGB-D), computes the candidate channels of the next RTS schema on every frame (pose "
        "observability, residuals, the optical-flow second opinion) and the label, and reports per source and "
        "pooled each channel's Spearman rho with the label and its partial rho given the motion statistic.",
    )
    p.add_argument("sources", nargs="+", help="KIND:PATH sources with ground truth")
    p.add_argument("--out", type=Path, required=True, help="folder for frames.csv, correlations.csv and .md")
    p.set_defaults(func=_candidates)

    p = sub.add_parser(
        "coverage",
        help="the predicted pose covariance against the label on a build's test sets, as computed and scaled",
        description="For every labelled frame of the build's runs (their kept device sessions' pose_covariance.csv), "
        "the label's pair's predicted sigma; per round and test set of the splits, the share of labels within 1 and "
        "2 sigma, beside a Gaussian's, as computed and with sigma scaled by a factor fitted on the round's training "
        "runs.",
    )
    p.add_argument("roots", type=Path, nargs="+", help="dataset folders (built with keep_sessions)")
    p.add_argument("--splits", type=Path, required=True, help="splits JSON of these folders")
    p.add_argument("--rounds", type=_ints, help="comma-separated rounds (default: all)")
    p.add_argument(
        "--predictions",
        type=Path,
        action="append",
        help="an evaluation's predictions.csv (repeatable): also the covariance scaled to each row's estimate",
    )
    p.add_argument("--out", type=Path, required=True, help="folder for covariance_coverage.csv and .md")
    p.set_defaults(func=_coverage)

    p = sub.add_parser("splits", help="grouped cross-validation splits by trajectory and motion group (JSON)")
    p.add_argument("roots", type=Path, nargs="+", help="dataset folders split together (e.g. pretraining + others)")
    p.add_argument("--out", type=Path, required=True, help="JSON file to write")
    p.add_argument(
        "--heldout",
        type=_names,
        help="the same held-out environments in every round ('' for none; default: configs/dataset.toml)",
    )
    p.add_argument(
        "--heldout-per-round",
        type=int,
        help="held-out rooms per round, different in every round (default: configs/dataset.toml)",
    )
    p.add_argument(
        "--heldout-cameras",
        type=_names,
        help="held-out camera models, e.g. kinect_v1 for leave-one-camera-out (default: configs/dataset.toml;"
        " '' for none)",
    )
    p.add_argument("--rounds", type=int, help="cross-validation rounds (default: configs/dataset.toml)")
    p.add_argument(
        "--final",
        action="store_true",
        help="instead of rounds, one round for the model to ship: every run outside the lockbox trains but a "
        "validation trajectory per motion group; no test set (only `seesys estimator lockbox` judges it)",
    )
    p.set_defaults(func=_splits)

    p = sub.add_parser("sample", help="regenerate the embedded demo sample (data/sample) with the generator")
    p.add_argument("--out", type=Path, required=True, help="sample folder (replaced)")
    p.add_argument("--env", help="environment preset (default: [sample] of configs/dataset.toml)")
    p.add_argument("--motion", help="motion (default: [sample] of configs/dataset.toml)")
    p.add_argument("--seed", type=int, help="seed (default: [sample] of configs/dataset.toml)")
    p.set_defaults(func=_sample)

    p = sub.add_parser("label", help="true pose-error label of every frame of one session folder (CSV)")
    p.add_argument("session", type=Path, help="a session folder with groundtruth.tum (seesys track / monitor run)")
    p.add_argument("--out", type=Path, required=True, help="CSV file: timestamp, error_m, status, scale")
    p.add_argument(
        "--labelled-only",
        action="store_true",
        help="keep only labelled frames (an estimate log for `seesys advisory render`)",
    )
    p.set_defaults(func=_label)
