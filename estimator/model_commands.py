"""``seesys estimator train | train-table | evaluate | lockbox | finetune | finetune-curve | export | estimate``: thin
wrappers over :mod:`estimator.deepsee`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from estimator.deepsee.rows import DEEPSEE, ROW_NAMES, row
from estimator.jobs import add_ray_argument
from seesys.core.errors import SeesysError
from seesys.io import resources

# torch, onnx and the model code are imported inside the commands: every `seesys` command builds this parser.


def _device(name: str, threads: int | None):
    import torch

    if threads is not None:
        if threads < 1:
            raise SeesysError("--threads must be at least 1")
        torch.set_num_threads(threads)
    if name == "cuda" and not torch.cuda.is_available():
        raise SeesysError(
            f"--device cuda: no CUDA device (this torch is {torch.__version__}; the project pins the CPU build)"
        )
    return torch.device(name)


def _ints(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _rows(text: str) -> list[str]:
    names = list(ROW_NAMES) if text == "all" else [v.strip() for v in text.split(",") if v.strip()]
    for name in names:
        row(name)
    return names


def _provenance(args: argparse.Namespace) -> dict:
    return {"data": [str(p) for p in args.data], "splits": str(args.splits)}


def _context(args: argparse.Namespace, extra: dict):
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.loop import progress_bar
    from estimator.deepsee.stages import TrainContext
    from seesys.io.core_settings import load_window_config

    device = _device(args.device, args.threads)
    return TrainContext(
        load_estimator_config(),
        args.schedule,
        load_window_config(),
        device,
        progress_bar(),
        {**_provenance(args), **extra},
    )


def _train(args: argparse.Namespace) -> int:
    from estimator.dataset.splits import read_splits
    from estimator.deepsee.data import split_windows
    from estimator.deepsee.stages import train_row

    ctx = _context(args, {"round": args.round})
    data = split_windows(args.data, read_splits(args.splits, args.data), args.round)
    with ctx.progress:
        model = train_row(args.out, row(args.row), data, ctx, args.pretrained)
    print(f"trained {args.row} (round {args.round}, {args.schedule} schedule, {ctx.device}) -> {model}")
    return 0


def _train_table_on_ray(args: argparse.Namespace) -> int:
    from estimator.dataset.splits import read_splits
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.loop import progress_bar
    from estimator.deepsee.table import TrainSpec, table_jobs
    from estimator.jobs import load_ray_settings, ray_executor
    from seesys.io.core_settings import load_window_config

    if args.threads is not None and args.threads < 1:
        raise SeesysError("--threads must be at least 1")
    threads = args.threads or load_ray_settings().train_cpus
    spec = TrainSpec(
        load_estimator_config(), args.schedule, load_window_config(), args.device, threads, _provenance(args)
    )
    # The cluster first: a bad --ray address is the error the user gets, whatever else is wrong.
    with ray_executor(args.ray or None) as executor, progress_bar() as progress:
        jobs = table_jobs(args.data, read_splits(args.splits, args.data), args.rounds, args.rows, args.runs, spec)
        executor.run(jobs, progress)
    for r in args.rounds:
        print(f"round {r}: {len(jobs) // len(args.rounds)} rows trained under {args.runs} (on Ray)")
    return 0


def _train_table(args: argparse.Namespace) -> int:
    from estimator.dataset.splits import read_splits
    from estimator.deepsee.table import train_table

    if args.ray is not None:
        return _train_table_on_ray(args)
    splits = read_splits(args.splits, args.data)
    for r in args.rounds:
        ctx = _context(args, {"round": r})
        with ctx.progress:
            models = train_table(args.data, splits, r, args.rows, args.runs, ctx)
        print(f"round {r}: {len(models)} rows trained under {args.runs}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from estimator.dataset.splits import read_splits
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.evaluate import evaluate
    from estimator.deepsee.report import write_report
    from seesys.io.core_settings import load_pulse_settings, load_window_config

    config = load_estimator_config()
    pulses = load_pulse_settings()
    device = _device(args.device, None)
    splits = read_splits(args.splits, args.data)
    result = evaluate(
        args.data, splits, args.runs, args.rounds, args.sessions or [], config, pulses, load_window_config(), device
    )
    notes = [f"Data: {', '.join(str(p) for p in args.data)}; splits {args.splits}; models under {args.runs}."]
    if args.sessions:
        notes.append(f"Out-of-domain sessions: {', '.join(str(s) for s in args.sessions)}.")
    path = write_report(result, config, pulses, args.out, notes)
    print(path.read_text())
    print(f"wrote {path}")
    return 0


def _lockbox(args: argparse.Namespace) -> int:
    from estimator.dataset.splits import read_splits
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.evaluate import evaluate_lockbox
    from estimator.deepsee.report import write_report
    from seesys.io.core_settings import load_pulse_settings, load_window_config

    config = load_estimator_config()
    pulses = load_pulse_settings()
    model = _default_model(args)
    splits = read_splits(args.splits, args.data)
    result = evaluate_lockbox(
        args.data,
        splits,
        model,
        args.round,
        config,
        pulses,
        load_window_config(),
        _device(args.device, None),
        args.row,
        args.fresh,
    )
    box = splits.lockbox
    where = f" ({box.environment}, {box.camera_model})" if box else ""
    fresh = f" A fresh lockbox: the runs of {', '.join(str(p) for p in args.fresh)} only." if args.fresh else ""
    notes = [
        f"The lockbox{where} judged for {model}, "
        f"trained on round {args.round} of {args.splits}; the reference rows are fitted on that round's "
        f"training data. Data: {', '.join(str(p) for p in args.data)}.{fresh}"
    ]
    path = write_report(result, config, pulses, args.out, notes)
    print(path.read_text())
    print(f"wrote {path}")
    return 0


def _default_model(args: argparse.Namespace) -> Path:
    from estimator.deepsee.config import load_estimator_config

    if args.model is not None:
        return args.model
    shipped = resources.resolve(load_estimator_config().shipped_model)
    if not shipped.is_file():
        raise SeesysError(
            f"no shipped model at {shipped} yet; pass --model MODEL (a file from `seesys estimator train`)"
        )
    return shipped


def _positive_minutes(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"minutes must be a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"minutes must be above 0, got {text}")
    return value


def _minutes_list(text: str) -> list[float]:
    return [_positive_minutes(part) for part in text.split(",")]


def _finetune_curve(args: argparse.Namespace) -> int:
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.finetune import learning_curve
    from estimator.deepsee.loop import progress_bar
    from seesys.io.core_settings import load_pulse_settings, load_window_config

    progress = progress_bar()
    with progress:
        table = learning_curve(
            _default_model(args),
            args.sessions,
            args.held_out,
            args.minutes,
            args.out,
            load_estimator_config(),
            load_window_config(),
            _device(args.device, args.threads),
            progress,
            load_pulse_settings(),
        )
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(f"-> {args.out / 'learning_curve.csv'}")
    return 0


def _finetune(args: argparse.Namespace) -> int:
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.finetune import finetune
    from estimator.deepsee.loop import progress_bar
    from seesys.io.camera_check import load_scale_settings, sessions_scale_line
    from seesys.io.core_settings import load_label_config, load_pulse_settings, load_window_config

    config = load_estimator_config()
    device = _device(args.device, args.threads)
    run_dir = args.run or args.out.with_name(args.out.stem + "_finetune_run")
    progress = progress_bar()
    with progress:
        result = finetune(
            _default_model(args),
            args.sessions,
            args.out,
            run_dir,
            config,
            load_window_config(),
            device,
            progress,
            {"command": " ".join(sys.argv)},
            args.held_out or [],
            load_pulse_settings(),
            None if args.minutes is None else 60.0 * args.minutes,
        )
    print(
        f"fine-tuned on {len(args.sessions)} sessions ({result.train_windows} training windows, "
        f"{result.validation_windows} validation windows, the last "
        f"{100 * config.finetune.validation_fraction:.0f} % of each session): validation RMSE "
        f"{result.rmse_before_cm:.3f} cm before, {result.rmse_after_cm:.3f} cm after -> {result.model}"
    )
    print(sessions_scale_line(args.sessions, load_scale_settings(), load_label_config().association_max_dt_s))
    before, after = result.held_out_before, result.held_out_after
    if before is not None and after is not None:  # both judged, or neither (no held-out windows)
        print(f"held-out sessions ({before.windows} windows, never trained on):")
        for name, scores in (("before", before), ("after", after)):
            print(
                f"  {name:6} RMSE {scores.rmse_cm:.3f} cm, within 1 mm-2 cm {scores.rmse_paper_range_cm:.3f} cm, "
                f"Spearman {scores.spearman:.2f}, advisory agreement {scores.agreement:.2f}, kappa "
                f"{scores.kappa:.2f}, recall >= 12 mm {scores.recall_large:.2f} ({scores.large_bins} of "
                f"{scores.bins} bins)"
            )
        for name, scores in (result.held_out_references or {}).items():
            print(
                f"  reference {name} (fitted on the same training windows): advisory agreement "
                f"{scores.agreement:.2f}, kappa {scores.kappa:.2f}, AURG {scores.aurg:.2f}"
            )
    return 0


def _export_forest(args: argparse.Namespace) -> int:
    from estimator.artefact.onnx_model import OnnxModel, training_cameras
    from estimator.artefact.transforms import LabelTransform
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.forest_export import FOREST_PARITY_TOLERANCE, export_forest_onnx, forest_parity, psd_shape_of
    from estimator.deepsee.predictors import read_forest
    from seesys.io.core_settings import load_window_config

    transform = LabelTransform(load_estimator_config().label_transform.k)
    windows = load_window_config()
    record = read_forest(args.model, windows, transform)
    path = export_forest_onnx(
        record,
        args.out,
        windows.rts_length,
        psd_shape_of(record["compatibility"], windows.psd_samples),
        training_cameras(record.get("training", {})),
    )
    difference = forest_parity(record["forest"], OnnxModel(path, transform, windows))
    if difference > FOREST_PARITY_TOLERANCE:
        raise SeesysError(
            f"{path}: ONNX Runtime differs from scikit-learn by {difference:.2e} (> {FOREST_PARITY_TOLERANCE:g})"
        )
    print(
        f"exported {args.model} -> {path} ({path.stat().st_size / 1e6:.1f} MB); parity with scikit-learn: max abs "
        f"difference {difference:.1e} on the transformed scale"
    )
    return 0


def _export(args: argparse.Namespace) -> int:
    if args.model.suffix == ".pkl":
        return _export_forest(args)
    from estimator.artefact.onnx_model import training_cameras
    from estimator.artefact.transforms import LabelTransform
    from estimator.deepsee.checkpoint import load_model, payload_standardisation
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.export import PARITY_TOLERANCE, OnnxModel, export_onnx, parity
    from estimator.deepsee.ordinal import model_thresholds
    from seesys.io.core_settings import load_window_config

    transform = LabelTransform(load_estimator_config().label_transform.k)
    windows = load_window_config()
    model, payload = load_model(args.model, transform, windows)
    path = export_onnx(
        model,
        args.out,
        windows,
        transform,
        payload["compatibility"],
        training_cameras(payload.get("training", {})),
        payload_standardisation(payload, args.model),
    )
    difference = parity(model, OnnxModel(path, transform, windows))
    if difference > PARITY_TOLERANCE:
        raise SeesysError(f"{path}: ONNX Runtime differs from PyTorch by {difference:.2e} (> {PARITY_TOLERANCE:g})")
    outputs = "the transformed scale" + (" and the head's probabilities" if model_thresholds(model) else "")
    print(
        f"exported {args.model} -> {path} ({path.stat().st_size / 1e6:.1f} MB); parity with PyTorch: max abs "
        f"difference {difference:.1e} on {outputs}"
    )
    return 0


def _estimate(args: argparse.Namespace) -> int:
    from estimator.artefact.transforms import LabelTransform
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.estimate import estimate_session
    from estimator.deepsee.predictors import load_predictor
    from estimator.service.broker import default_model
    from estimator.service.config import load_service_config
    from seesys.io.core_settings import load_window_config

    config = load_estimator_config()
    windows = load_window_config()
    # By default the model the service serves: a preview of what the advisory would say live.
    model = args.model if args.model is not None else default_model(load_service_config(), None)
    predictor = load_predictor(
        model, LabelTransform(config.label_transform.k), config.evaluation.batch_size, windows=windows
    )
    table = estimate_session(predictor, args.session, windows, args.out)
    head = ", with the ordinal head's probabilities and class" if predictor.thresholds_m else ""
    print(
        f"{len(table)} estimates (median {1000 * table.error_m.median():.1f} mm{head}) -> {args.out}; "
        f"listen with `seesys advisory render --estimates {args.out} --out preview.wav`"
    )
    return 0


def _data_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, nargs="+", required=True, help="dataset folders (seesys dataset build)")
    p.add_argument("--splits", type=Path, required=True, help="splits JSON of those folders (seesys dataset splits)")


def _training_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--schedule",
        choices=("reduced", "full"),
        default="reduced",
        help="training schedule of configs/estimator.toml (default: reduced, about an hour on 2 cores)",
    )
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``seesys estimator`` to the command line."""
    estimator = subparsers.add_parser("estimator", help="train, evaluate, fine-tune, export and run DeepSEE")
    sub = estimator.add_subparsers(dest="estimator_command", metavar="ESTIMATOR_COMMAND", required=True)

    p = sub.add_parser("train", help="train one Table 3 row on a round of the splits (resumable: rerun to continue)")
    _data_arguments(p)
    p.add_argument("--round", type=int, default=0, help="cross-validation round (default 0)")
    p.add_argument("--row", default="deepsee", choices=ROW_NAMES, help="Table 3 row (default deepsee)")
    p.add_argument("--pretrained", type=Path, help="a DeepSEE run folder whose pretrained encoders to start from")
    p.add_argument("--out", type=Path, required=True, help="run folder (created, or resumed)")
    _training_arguments(p)
    p.set_defaults(func=_train)

    p = sub.add_parser("train-table", help="train every Table 3 row of the given rounds (resumable)")
    _data_arguments(p)
    p.add_argument("--rounds", type=_ints, default=[0], help="comma-separated rounds (default 0)")
    p.add_argument("--rows", type=_rows, default=list(ROW_NAMES), help="comma-separated rows, or all (default)")
    p.add_argument("--runs", type=Path, required=True, help="folder for round_<r>/<row>/ run folders")
    _training_arguments(p)
    add_ray_argument(
        p,
        "each row × round (reserving --threads CPUs, default train_cpus of configs/ray.toml, and a "
        "GPU with --device cuda)",
    )
    p.set_defaults(func=_train_table)

    p = sub.add_parser("evaluate", help="Table 3 report of the trained rows (Markdown, CSV, PNG)")
    _data_arguments(p)
    p.add_argument("--runs", type=Path, required=True, help="the train-table folder")
    p.add_argument("--rounds", type=_ints, default=[0], help="comma-separated rounds (default 0)")
    p.add_argument("--sessions", type=Path, nargs="*", help="labelled session folders judged as out-of-domain data")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    p.add_argument("--out", type=Path, required=True, help="report folder")
    p.set_defaults(func=_evaluate)

    p = sub.add_parser("lockbox", help="judge a shipped model, once, on the lockbox's runs (never for a design choice)")
    _data_arguments(p)
    p.add_argument("--model", type=Path, help="the shipped model (default: the shipped model)")
    p.add_argument("--round", type=int, default=0, help="the round of the splits the model was trained on (default 0)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    p.add_argument("--out", type=Path, required=True, help="report folder")
    p.add_argument("--row", default=DEEPSEE, help=f"the model's row name in the report (default {DEEPSEE})")
    p.add_argument(
        "--fresh",
        type=Path,
        nargs="+",
        help="dataset folders of new renders of the lockbox's room and camera: judged instead of the splits' own "
        "lockbox runs (when those have been judged once already)",
    )
    p.set_defaults(func=_lockbox)

    p = sub.add_parser("finetune", help="stage (d) on labelled session folders (real cameras with ground truth)")
    p.add_argument("--sessions", type=Path, nargs="+", required=True, help="session folders with groundtruth.tum")
    p.add_argument(
        "--held-out",
        type=Path,
        nargs="+",
        help="whole sessions with groundtruth.tum never trained on, judged before and after",
    )
    p.add_argument("--model", type=Path, help="model to start from (default: the shipped model)")
    p.add_argument("--out", type=Path, required=True, help="the fine-tuned model file")
    p.add_argument("--run", type=Path, help="run folder for its metrics and checkpoints (default: next to --out)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    p.add_argument(
        "--minutes",
        type=_positive_minutes,
        help="fine-tune on the first MINUTES of the sessions only, in their order (default: all)",
    )
    p.set_defaults(func=_finetune)

    p = sub.add_parser(
        "finetune-curve",
        help="the fine-tuning learning curve: fine-tune on the first 0.5, 1, 2, 5 "
        "minutes of an unseen camera's sessions, judge each on held-out ones",
    )
    p.add_argument("--sessions", type=Path, nargs="+", required=True, help="the camera's labelled sessions, in order")
    p.add_argument("--held-out", type=Path, nargs="+", required=True, help="its sessions that judge every budget")
    p.add_argument(
        "--minutes",
        type=_minutes_list,
        default=[0.5, 1.0, 2.0, 5.0],
        help="comma-separated budgets in minutes (default: 0.5,1,2,5)",
    )
    p.add_argument("--model", type=Path, help="model to start from (default: the shipped model)")
    p.add_argument("--out", type=Path, required=True, help="folder: learning_curve.csv, each budget's model and run")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    p.set_defaults(func=_finetune_curve)

    p = sub.add_parser(
        "export", help="export a model to one ONNX file and check it against PyTorch (or scikit-learn for a forest)"
    )
    p.add_argument("model", type=Path, help="model file: DeepSEE's model.pt, or the random forest's model.pkl")
    p.add_argument("--out", type=Path, required=True, help="ONNX file to write")
    p.set_defaults(func=_export)

    p = sub.add_parser("estimate", help="per-frame estimates of a logged session (CSV for seesys advisory render)")
    p.add_argument("session", type=Path, help="session folder with rts.csv and psd/ (seesys monitor run)")
    p.add_argument(
        "--model", type=Path, help="model file, .pt, .pkl or .onnx (default: the served model, configs/service.toml)"
    )
    p.add_argument("--out", type=Path, required=True, help="CSV: frame_index, timestamp, error_m")
    p.set_defaults(func=_estimate)
