"""``seesys study simulate`` and the child it starts for each session, ``seesys study simulate-session``: thin
wrappers over :mod:`seesys_app.simulate.study`."""

from __future__ import annotations

import argparse
import signal
import time
from dataclasses import replace
from pathlib import Path

from seesys.io.arguments import positive_int
from seesys.io.processes import stop_on_signals
from seesys_app.simulate.config import CONDITIONS, DESIGNS


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def _conditions(text: str) -> list[str]:
    names = [c.strip() for c in text.split(",") if c.strip()]
    unknown = [c for c in names if c not in CONDITIONS]
    if unknown or len(names) < 2:
        raise argparse.ArgumentTypeError(f"two or more of {', '.join(CONDITIONS)}, comma-separated; got {text}")
    return names


def simulate_command(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

    from estimator.service.broker import default_model
    from estimator.service.config import load_service_config
    from seesys_app.simulate.config import load_simulate_config
    from seesys_app.simulate.study import run_study

    # SIGTERM stops the study as Ctrl-C does; SIGINT is restored where a shell started the command with it ignored.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    cfg = load_simulate_config()
    study = replace(
        cfg.study,
        **{
            k: v
            for k, v in (
                ("participants_per_condition", args.participants),
                ("conditions", args.conditions),
                ("design", args.design),
                ("processes", args.processes),
                ("operator_seed", args.operator_seed),
            )
            if v is not None
        },
    )
    task = replace(
        cfg.task, **{k: v for k, v in (("objects", args.objects), ("max_task_s", args.max_task_s)) if v is not None}
    )
    cfg = replace(cfg, study=study, task=task)
    model = default_model(load_service_config(), args.model)
    started = time.monotonic()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f} s"),
        TimeElapsedColumn(),
        transient=True,
    ) as progress:
        bars: dict[str, TaskID] = {}

        def show(name: str, seconds: float, note: str) -> None:
            if name not in bars:
                bars[name] = progress.add_task(name, total=cfg.task.max_task_s)
            elif not note:
                progress.update(bars[name], completed=seconds)
            else:
                progress.console.print(f"{name}: {note}", soft_wrap=True)
                progress.remove_task(bars.pop(name))

        outcome = run_study(args.out, cfg, model, show=show)
    minutes = (time.monotonic() - started) / 60
    print(
        f"{outcome.study}: {outcome.done} of {outcome.sessions} sessions done ({minutes:.1f} min); "
        f"next: seesys analyze {outcome.study}"
    )
    for line in outcome.failed:
        print(f"  failed: {line}")
    return 0 if outcome.done == outcome.sessions else 1


def simulate_session_command(args: argparse.Namespace) -> int:
    """One session of a simulated study: 0 when its task completed or timed out, 130 when a signal stopped it."""
    import cv2

    from seesys_app.simulate.study import run_session

    # SIGINT and SIGTERM end the session at its next frame with its files final. A flag, not KeyboardInterrupt: an
    # exception could land between a frame's rows and its count, or in the closing of the files.
    cv2.setNumThreads(1)  # parallelism is across sessions: OpenCV's own threads would only contend with them
    with stop_on_signals() as stop:
        status = run_session(args.study, args.participant, args.condition, args.model, stop.is_set)
    return 130 if status == "interrupted" else 0


def register(study_commands: argparse._SubParsersAction) -> None:
    """Add ``simulate`` and ``simulate-session`` to ``seesys study``."""
    p = study_commands.add_parser(
        "simulate",
        help="a closed-loop simulated study: simulated operators through SLAM, model and advisory",
        description="Simulated operators scan objects in a rendered room; every frame goes through ORB-SLAM3, the "
        "RTS monitor, the served model (configs/service.toml) and the advisory, and the pulses change how the "
        "operator moves. Writes a study folder that `seesys analyze` reads; run it again to resume. "
        "Defaults: configs/simulate.toml.",
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the study folder (new, or one to resume)")
    p.add_argument("--participants", type=positive_int, metavar="N", help="simulated participants per condition")
    p.add_argument(
        "--conditions",
        type=_conditions,
        metavar="A,B,...",
        help=f"conditions ({', '.join(CONDITIONS)}; yoked and oracle are simulation-only controls)",
    )
    p.add_argument(
        "--design",
        choices=DESIGNS,
        help="between: one condition per participant; within: the same simulated operator in every condition (paired)",
    )
    p.add_argument("--objects", type=positive_int, metavar="N", help="objects to scan")
    p.add_argument("--max-task-s", type=_seconds, metavar="S", help="end a session that has not finished by then")
    p.add_argument("--processes", type=positive_int, metavar="P", help="sessions simulated at once")
    p.add_argument(
        "--operator-seed",
        type=int,
        metavar="S",
        help="the seed the simulated operators are drawn from (a pilot uses another seed than its study)",
    )
    p.add_argument("--model", type=Path, help="the ONNX model (default: configs/service.toml)")
    p.set_defaults(func=simulate_command)
    s = study_commands.add_parser(
        "simulate-session",
        help="one session of a simulated study (what `seesys study simulate` starts for each session)",
        description="Simulates one session of a study folder that `seesys study simulate` made, with the settings "
        "its simulation.json records, into a new attempt of the session (earlier ones superseded). "
        "`seesys study simulate` starts one for each session; run by hand, it redoes that session.",
    )
    s.add_argument("--study", type=Path, required=True, metavar="DIR", help="the study folder")
    s.add_argument("--participant", required=True, metavar="ID", help="the simulated participant (P03)")
    s.add_argument("--condition", choices=CONDITIONS, required=True, help="the session's condition")
    s.add_argument("--model", type=Path, required=True, help="the ONNX model the study runs")
    s.set_defaults(func=simulate_session_command)
