"""A training run's folder: the resolved configuration, the hardware, per-epoch metrics and loss curves.

::

    RUN/config.json      everything the run was asked to do (configuration, schedule, variant, data, round)
    RUN/hardware.json    where and how it ran: command line, device, CPU, GPU, threads, load, versions (per invocation)
    RUN/metrics.csv      one row per epoch of every stage: stage, epoch, train_loss, val_loss, lr, seconds, best
    RUN/loss_curves.png  train and validation loss of every stage, redrawn after each epoch
    RUN/state/           per-stage checkpoints (resume) and best weights
    RUN/model.pt         the finished model (estimator.deepsee.checkpoint)
"""

from __future__ import annotations

import csv
import json
import os
import platform
import sys
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd
import torch

from seesys.core.errors import SeesysError
from seesys.io.session_files import utc_now

CONFIG_JSON = "config.json"
HARDWARE_JSON = "hardware.json"
METRICS_CSV = "metrics.csv"
LOSS_PNG = "loss_curves.png"
STATE_DIR = "state"
MODEL_PT = "model.pt"
METRIC_COLUMNS = ("stage", "epoch", "train_loss", "val_loss", "lr", "seconds", "best")


@dataclass(frozen=True)
class EpochRecord:
    stage: str
    epoch: int
    train_loss: float
    val_loss: float
    lr: float
    seconds: float
    best: bool


def hardware(device: torch.device) -> dict:
    """What the run is using: for the record of what ran where."""
    info = {
        "time": utc_now(),
        "command": " ".join(sys.argv),
        "device": str(device),
        "platform": platform.platform(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "load_average": list(os.getloadavg()),
    }
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    for package in ("numpy", "scikit-learn", "onnxruntime"):
        try:
            info[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            info[package] = "not installed"
    return info


class RunFolder:
    """Creates or resumes a run folder; a resumed run must have been asked the same thing."""

    def __init__(self, path: Path, config: dict, device: torch.device):
        self.path = Path(path)
        self.state = self.path / STATE_DIR
        self.state.mkdir(parents=True, exist_ok=True)
        config_path = self.path / CONFIG_JSON
        resolved = json.loads(json.dumps(config, default=str))
        if config_path.exists():
            earlier = json.loads(config_path.read_text())
            if earlier != resolved:
                changed = sorted(k for k in set(earlier) | set(resolved) if earlier.get(k) != resolved.get(k))
                raise SeesysError(
                    f"{self.path} holds a run with a different {', '.join(changed)}; resume it with the "
                    f"same arguments or train into a new folder"
                )
        else:
            config_path.write_text(json.dumps(resolved, indent=2) + "\n")
        hardware_path = self.path / HARDWARE_JSON
        entries = json.loads(hardware_path.read_text()) if hardware_path.exists() else []
        hardware_path.write_text(json.dumps(entries + [hardware(device)], indent=2) + "\n")

    def record(self, row: EpochRecord) -> None:
        path = self.path / METRICS_CSV
        new = not path.exists()
        with open(path, "a", newline="") as f:
            writer = csv.writer(f)
            if new:
                writer.writerow(METRIC_COLUMNS)
            writer.writerow(
                [
                    row.stage,
                    row.epoch,
                    f"{row.train_loss:.6g}",
                    f"{row.val_loss:.6g}",
                    f"{row.lr:.3g}",
                    f"{row.seconds:.1f}",
                    int(row.best),
                ]
            )

    def metrics(self) -> pd.DataFrame:
        path = self.path / METRICS_CSV
        return pd.read_csv(path) if path.exists() else pd.DataFrame(columns=list(METRIC_COLUMNS))

    def plot(self) -> Path:
        """Loss curves, one panel per stage (a resumed epoch's row replaces the earlier one)."""
        table = self.metrics().drop_duplicates(["stage", "epoch"], keep="last")
        stages = list(dict.fromkeys(table.stage))
        fig, axes = plt.subplots(1, max(len(stages), 1), figsize=(4 * max(len(stages), 1), 3.2), squeeze=False)
        for ax, stage in zip(axes[0], stages):
            rows = table[table.stage == stage]
            ax.plot(rows.epoch, rows.train_loss, marker="o", label="train")
            if rows.val_loss.notna().any():
                ax.plot(rows.epoch, rows.val_loss, marker="o", label="validation")
            ax.set_title(stage)
            ax.set_xlabel("epoch")
            ax.set_ylabel("loss")
            ax.legend()
        fig.tight_layout()
        out = self.path / LOSS_PNG
        fig.savefig(out, dpi=90)
        plt.close(fig)
        return out
