"""One command for a round's whole Table 3: DeepSEE first, then every ablation from DeepSEE's pretrained encoders
(on the schedule's ablation stages), then the LSTM and the random forest, each in ``RUNS/round_<r>/<row>/``.
Every row is resumable on its own; a finished row is not trained again."""

from __future__ import annotations

from pathlib import Path

from estimator.dataset.splits import Splits
from estimator.deepsee.data import split_windows
from estimator.deepsee.evaluate import round_folder
from estimator.deepsee.rows import DEEPSEE, training_order
from estimator.deepsee.stages import ENCODERS_PT, TrainContext, train_row


def train_table(roots: list[Path], splits: Splits, round_index: int, rows: list[str], runs: Path,
                ctx: TrainContext) -> list[Path]:
    """Train ``rows`` of round ``round_index``; returns their model files."""
    data = split_windows(roots, splits, round_index)
    folder = round_folder(runs, round_index)
    encoders = folder / DEEPSEE / "state" / ENCODERS_PT
    models = []
    for row in training_order(rows):
        pretrained = folder / DEEPSEE if row.ablation and row.ssl and encoders.is_file() else None
        ctx.progress.console.log(f"round {round_index}: {row.label}"
                                 + (" (from DeepSEE's pretrained encoders)" if pretrained else ""))
        models.append(train_row(folder / row.name, row, data, ctx, pretrained))
    return models
