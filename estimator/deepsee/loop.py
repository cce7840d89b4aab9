"""One training stage: epochs of seeded batches, a checkpoint after every epoch, early stopping on the validation
loss, a rich progress bar with the loss and the time left.

Resuming: the stage's checkpoint (``state/<stage>.pt``) holds the weights, the optimizer, the epoch reached and the
early-stopping counters. The weights a stage starts from are validated first (epoch 0 of its metrics) and count
as its best until an epoch beats them. Batch order depends only on the seed, the stage and the epoch, so a resumed
stage sees the batches an uninterrupted one would have seen. A finished stage (its epochs done, or stopped early) is
skipped on resume, its best weights loaded; giving it more epochs than it had continues it.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from torch import nn

from estimator.deepsee.checkpoint import save_atomic
from estimator.deepsee.config import StageSchedule
from estimator.deepsee.run_folder import EpochRecord, RunFolder

GRAD_CLIP = 1.0


def progress_bar() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("loss {task.fields[loss]}"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
    )


def stage_seed(seed: int, stage: str, epoch: int) -> int:
    return (seed * 1_000_003 + zlib.crc32(stage.encode()) + 7919 * epoch) % 2**32


def epoch_batches(n: int, schedule: StageSchedule, seed: int, stage: str, epoch: int) -> list[np.ndarray]:
    """The batches of one epoch: a seeded permutation of the n samples, at most ``steps_per_epoch`` batches."""
    order = np.random.default_rng(stage_seed(seed, stage, epoch)).permutation(n)
    batches = [order[i : i + schedule.batch_size] for i in range(0, n, schedule.batch_size)]
    return batches[: schedule.steps_per_epoch] if schedule.steps_per_epoch > 0 else batches


@dataclass(frozen=True)
class StageResult:
    name: str
    epochs: int
    best_val: float
    stopped_early: bool


def _checkpoint_paths(run: RunFolder, name: str) -> tuple[Path, Path]:
    return run.state / f"{name}.pt", run.state / f"{name}.best.pt"


def run_stage(
    run: RunFolder,
    name: str,
    module: nn.Module,
    parameters: Iterable[nn.Parameter],
    schedule: StageSchedule,
    n_train: int,
    step: Callable[[np.ndarray, torch.Generator], torch.Tensor],
    validate: Callable[[], float] | None,
    seed: int,
    progress: Progress,
) -> StageResult:
    """Train ``parameters`` (part of ``module``, whose whole state is checkpointed) for the stage's epochs.

    ``step(batch_indices, generator)`` returns the batch's loss; ``validate()`` the validation loss (lower is
    better; None: no validation, no early stopping, the last weights are kept).
    """
    state_path, best_path = _checkpoint_paths(run, name)
    parameters = [p for p in parameters if p.requires_grad]
    optimizer = torch.optim.AdamW(parameters, lr=schedule.lr, weight_decay=schedule.weight_decay)
    epoch, best_val, bad_epochs, stopped = 0, float("inf"), 0, False
    if state_path.exists():
        saved = torch.load(state_path, map_location="cpu", weights_only=False)
        module.load_state_dict(saved["module"])
        optimizer.load_state_dict(saved["optimizer"])
        epoch, best_val, bad_epochs, stopped = (
            saved["epoch"],
            saved["best_val"],
            saved["bad_epochs"],
            saved["stopped_early"],
        )
    # A stage is done when it stopped early or reached its epochs: a schedule with more epochs extends it.
    done = stopped or epoch >= schedule.epochs
    steps = len(epoch_batches(n_train, schedule, seed, name, 0))
    task = progress.add_task(name, total=schedule.epochs * steps, completed=epoch * steps, loss="-")
    first_epoch = epoch
    if not done and epoch == 0 and validate is not None:
        # The starting weights compete too: a stage that never beats them (fine-tuning on a few sessions that
        # over-fits from the first epoch) ends with the weights it was given, not a worse epoch.
        start = time.perf_counter()
        best_val = validate()
        save_atomic(module.state_dict(), best_path)
        run.record(EpochRecord(name, 0, float("nan"), best_val, schedule.lr, time.perf_counter() - start, True))
    while not done and epoch < schedule.epochs:
        start = time.perf_counter()
        module.train()
        generator = torch.Generator().manual_seed(stage_seed(seed, name + ":noise", epoch))
        losses = []
        for batch in epoch_batches(n_train, schedule, seed, name, epoch):
            loss = step(batch, generator)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(parameters, GRAD_CLIP)
            optimizer.step()
            losses.append(float(loss.detach()))
            progress.update(task, advance=1, loss=f"{losses[-1]:.4f}")
        train_loss = float(np.mean(losses)) if losses else float("nan")
        val_loss = validate() if validate is not None else float("nan")
        improved = validate is not None and val_loss < best_val
        if improved:
            best_val, bad_epochs = val_loss, 0
            save_atomic(module.state_dict(), best_path)
        elif validate is not None:
            bad_epochs += 1
        epoch += 1
        stopped = validate is not None and bad_epochs >= schedule.patience
        done = stopped or epoch >= schedule.epochs
        progress.update(task, loss=f"{train_loss:.4f} / val {val_loss:.4f}")
        save_atomic(
            {
                "module": module.state_dict(),
                "optimizer": optimizer.state_dict(),
                "epoch": epoch,
                "best_val": best_val,
                "bad_epochs": bad_epochs,
                "stopped_early": stopped,
            },
            state_path,
        )
        run.record(EpochRecord(name, epoch, train_loss, val_loss, schedule.lr, time.perf_counter() - start, improved))
    progress.update(task, completed=schedule.epochs * steps)
    if epoch > first_epoch:
        run.plot()
    if best_path.exists():
        module.load_state_dict(torch.load(best_path, map_location="cpu", weights_only=True))
    return StageResult(name, epoch, best_val, stopped)
