"""One command for a round's whole Table 3: DeepSEE first, then every ablation from DeepSEE's pretrained encoders
(on the schedule's ablation stages), then the LSTM and the random forest, each in ``RUNS/round_<r>/<row>/``.
Every row is resumable on its own; a finished row is not trained again.

:func:`train_table` trains a round's rows here, one after the other, on the round's windows read once.
:func:`table_jobs` makes the same rows of several rounds into jobs for a :class:`~estimator.jobs.RayExecutor`:
each row × round is a Ray task that reads its round's windows itself and trains the row with the same
:func:`train_table_row`; an ablation that starts from DeepSEE's encoders waits for its round's DeepSEE task.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass
from pathlib import Path

from estimator.dataset.splits import Splits
from estimator.deepsee.config import EstimatorConfig
from estimator.deepsee.data import Windows, split_windows
from estimator.deepsee.evaluate import round_folder
from estimator.deepsee.rows import DEEPSEE, RANDOM_FOREST, Row, row, training_order
from estimator.deepsee.stages import ENCODERS_PT, TrainContext, train_row
from estimator.jobs import Job, JobEnv
from seesys.core.errors import SeesysError
from seesys.core.windows import WindowConfig


def train_table_row(
    folder: Path, table_row: Row, data: dict[str, Windows], ctx: TrainContext, round_index: int
) -> Path:
    """Train ``table_row`` into ``folder/<row>`` (``folder``: the round's); an ablation with self-supervised
    encoders starts from the round's DeepSEE encoders when they are there. Returns the model file."""
    encoders = folder / DEEPSEE / "state" / ENCODERS_PT
    pretrained = folder / DEEPSEE if table_row.ablation and table_row.ssl and encoders.is_file() else None
    ctx.progress.console.log(
        f"round {round_index}: {table_row.label}" + (" (from DeepSEE's pretrained encoders)" if pretrained else "")
    )
    return train_row(folder / table_row.name, table_row, data, ctx, pretrained)


def train_table(
    roots: list[Path], splits: Splits, round_index: int, rows: list[str], runs: Path, ctx: TrainContext
) -> list[Path]:
    """Train ``rows`` of round ``round_index``; returns their model files."""
    data = split_windows(roots, splits, round_index)
    folder = round_folder(runs, round_index)
    return [train_table_row(folder, r, data, ctx, round_index) for r in training_order(rows)]


@dataclass(frozen=True)
class TrainSpec:
    """A :class:`TrainContext` as values, for a row's task to make its own on whichever node runs it."""

    config: EstimatorConfig
    schedule_name: str
    windows: WindowConfig
    device: str  # cpu or cuda
    threads: int  # torch threads, and the CPUs the task reserves
    provenance: dict  # the data folders and splits; the round is added per job


def job_name(round_index: int, row_name: str) -> str:
    return f"round {round_index}: {row_name}"


def table_jobs(
    roots: list[Path], splits: Splits, rounds: list[int], rows: list[str], runs: Path, spec: TrainSpec
) -> list[Job]:
    """``rows`` × ``rounds`` as jobs, in training order per round. A row on cuda reserves a GPU (the random
    forest, which never uses one, does not); an ablation that starts from DeepSEE's encoders comes after its
    round's DeepSEE job when DeepSEE is among ``rows``. Paths are made absolute here: a task on another node does not
    run in this folder."""
    roots, runs = [Path(r).absolute() for r in roots], Path(runs).absolute()
    jobs = []
    for round_index in rounds:
        order = training_order(rows)
        deepsee = [job_name(round_index, DEEPSEE)] if any(r.name == DEEPSEE for r in order) else []
        for r in order:
            gpus = 1 if spec.device == "cuda" and r.kind != RANDOM_FOREST else 0
            after = tuple(deepsee) if r.ablation and r.ssl else ()
            jobs.append(
                Job(
                    job_name(round_index, r.name),
                    row_job,
                    (roots, splits, round_index, r.name, runs, spec),
                    cpus=spec.threads,
                    gpus=gpus,
                    after=after,
                )
            )
    return jobs


def row_job(
    roots: list[Path], splits: Splits, round_index: int, row_name: str, runs: Path, spec: TrainSpec, env: JobEnv
) -> Path:
    """One row × round (a job of :func:`table_jobs`): its round's windows, then :func:`train_table_row`."""
    import torch

    if spec.device == "cuda" and not torch.cuda.is_available():
        raise SeesysError(
            f"--device cuda: no CUDA device for the task on {socket.gethostname()} (this torch is {torch.__version__})"
        )
    torch.set_num_threads(spec.threads)
    ctx = TrainContext(
        spec.config,
        spec.schedule_name,
        spec.windows,
        torch.device(spec.device),
        env.progress,
        {**spec.provenance, "round": round_index},
    )
    data = split_windows(roots, splits, round_index)
    return train_table_row(round_folder(runs, round_index), row(row_name), data, ctx, round_index)
