"""``seesys`` subcommands of the estimator part: the dataset, the model and the service, and ``synth diversity``
(a report on rendered sequences through the device's image statistics)."""

from __future__ import annotations

import argparse
from pathlib import Path

from estimator import dataset_commands, model_commands, service_commands


def _diversity(args: argparse.Namespace) -> int:
    from estimator.diversity import diversity_report, write_report  # image statistics and plots: when it runs

    report = diversity_report(args.root, args.stride)
    paths = write_report(report, args.out)
    print((args.out / "diversity.md").read_text(), end="")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add this part's commands to the ``seesys`` command line."""
    dataset_commands.register(subparsers)
    model_commands.register(subparsers)
    service_commands.register(subparsers)
    return {}


def register_synth_commands(synth_commands: argparse._SubParsersAction) -> None:
    """Add ``diversity`` to ``seesys synth``."""
    p = synth_commands.add_parser(
        "diversity", help="per-environment image statistics of rendered sequences (paper Fig. 8)"
    )
    p.add_argument("root", type=Path, help="folder holding rendered sequences")
    p.add_argument("--out", type=Path, required=True, help="folder for diversity.csv/.md/.png")
    p.add_argument("--stride", type=int, default=5, help="use every N-th frame (default 5)")
    p.set_defaults(func=_diversity)
