"""``seesys study new|run|status``: the study's protocol, one participant's session, and who is done."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console
from rich.table import Table

from study.config import load_study_config
from study.protocol import make_protocol, read_protocol, write_protocol
from study.sessions import DONE_STATUSES, attempt_folders, phase_status


def new_command(args: argparse.Namespace) -> int:
    cfg = load_study_config().protocol
    conditions = args.conditions.split(",") if args.conditions else None
    protocol = make_protocol(cfg, args.per_condition, args.design, args.seed, conditions)
    path = write_protocol(args.study, protocol)
    print(
        f"{path}: {protocol.design}-subjects, {len(protocol.participants)} participants, conditions "
        f"{', '.join(protocol.conditions)}, seed {protocol.assignment_seed}"
    )
    for p in protocol.participants:
        print(f"  {p.id}  {' -> '.join(p.conditions)}")
    return 0


def run_command(args: argparse.Namespace) -> int:
    from study.operator import OperatorInput
    from study.runner import RunOptions, Session

    options = RunOptions(
        args.study,
        args.participant,
        args.phase,
        args.condition,
        args.source,
        args.mode,
        args.replay_estimates,
        args.restart,
        args.max_frames,
        args.pace,
        args.mocap,
    )
    console = Console(stderr=True)
    result = Session(options, load_study_config(), OperatorInput(), console).run()
    print(
        f"{result.attempt}: {result.status}, {result.frames} frames, {result.estimates} estimates, "
        f"{result.events} events"
    )
    return 0 if result.status in DONE_STATUSES else 130 if result.status == "interrupted" else 1


def status_command(args: argparse.Namespace) -> int:
    protocol = read_protocol(args.study)
    table = Table(title=f"{args.study} ({protocol.design}-subjects)")
    table.add_column("participant")
    table.add_column("condition")
    for phase in protocol.phases:
        table.add_column(phase)
    counts: dict[str, int] = {}
    for person in protocol.participants:
        for condition in person.conditions:
            cells = []
            for phase in protocol.phases:
                folder = protocol.phase_folder(args.study, person.id, phase, condition)
                state = phase_status(folder)
                attempts = len(attempt_folders(folder))
                cells.append(state + (f" ({attempts} attempts)" if attempts > 1 else ""))
            table.add_row(person.id, condition, *cells)
            counts[cells[-1].split()[0]] = counts.get(cells[-1].split()[0], 0) + 1
    console = Console()
    console.print(table)
    console.print(f"{protocol.analysed_phase}: " + ", ".join(f"{n} {state}" for state, n in sorted(counts.items())))
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser("new", help="write a study's protocol: conditions, participants, random assignment")
    p.add_argument("study", type=Path, metavar="DIR")
    p.add_argument("--per-condition", type=int, metavar="N", help="participants per condition (configs/study.toml)")
    p.add_argument("--design", choices=("between", "within"), help="between-subjects (default) or within")
    p.add_argument("--seed", type=int, help="assignment seed (configs/study.toml)")
    p.add_argument("--conditions", metavar="A,B,..", help="conditions (none, rotation, seesys)")
    p.set_defaults(func=new_command)

    p = commands.add_parser(
        "run",
        help="run one participant's session: device, estimates, advisory, mocap, events",
        description="Starts the device (seesys monitor run --stream), the advisory in the "
        "participant's condition, the mocap logger and optionally an estimate "
        "replay; logs estimates and the operator's events (keys i, o, n, q) into "
        "a new attempt folder of the participant. q ends the task and stops the "
        "session (stopped, exit 0); Ctrl-C interrupts it (interrupted, exit 130).",
    )
    p.add_argument("study", type=Path, metavar="DIR")
    p.add_argument("--participant", required=True, metavar="ID")
    p.add_argument("--phase", required=True, metavar="PHASE", help="a phase of the protocol (training, task)")
    p.add_argument("--condition", help="within-subjects: this condition instead of the next in the order")
    p.add_argument("--source", metavar="KIND:PATH", help="frame source (default configs/study.toml)")
    p.add_argument("--mode", choices=("rgbd", "mono"), help="SLAM mode (default configs/study.toml)")
    p.add_argument(
        "--replay-estimates",
        type=Path,
        metavar="CSV",
        help="publish these estimates (seesys advisory replay) instead of waiting for the estimator",
    )
    p.add_argument("--restart", action="store_true", help="record the phase again; earlier attempts are superseded")
    p.add_argument("--max-frames", type=int, metavar="N", help="stop the device after N frames")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument(
        "--pace",
        dest="pace",
        action="store_true",
        default=None,
        help="feed a recording at camera rate, as the participant's camera would (never waiting for "
        "ORB-SLAM3's mapping)",
    )
    pace.add_argument("--no-pace", dest="pace", action="store_false")
    mocap = p.add_mutually_exclusive_group()
    mocap.add_argument("--mocap", dest="mocap", action="store_true", default=None, help="log motion capture")
    mocap.add_argument("--no-mocap", dest="mocap", action="store_false")
    p.set_defaults(func=run_command)

    p = commands.add_parser("status", help="who is done, pending or incomplete")
    p.add_argument("study", type=Path, metavar="DIR")
    p.set_defaults(func=status_command)
