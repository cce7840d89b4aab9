"""Diversity of the rendered environments (paper Fig. 8): per-environment medians and spread of brightness,
contrast, entropy and Laplacian variance of the frames, as a table and a box-plot PNG.

The four image features are THE sensor-input RTS channels (``slam_monitor.image_features``), the Laplacian at the
reference camera's pixel size as the monitor computes it (camera normalisation, from each sequence's
``calibration.yaml``), so the report describes the data in the units the estimator sees.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd

from seesys.core.camera_normalisation import CameraNormalisation
from seesys.core.errors import SeesysError
from slam_monitor.image_features import image_features, reference_scale
from slam_monitor.monitor_config import load_monitor_config
from slam_monitor.sources import load_camera_config
from slam_monitor.sources.settings import folder_calibration

FEATURES = ("brightness", "contrast", "entropy", "laplacian")


@dataclass(frozen=True)
class DiversityReport:
    frames: pd.DataFrame  # one row per sampled frame: environment, motion_group, sequence, the four features
    summary: pd.DataFrame  # per environment: median, p10, p90 of each feature


def find_sequences(root: Path) -> list[Path]:
    """Rendered sequence folders under ``root`` (those holding a ``metadata.json`` and ``rgb.txt``)."""
    folders = sorted(p.parent for p in root.rglob("metadata.json") if (p.parent / "rgb.txt").is_file())
    if not folders:
        raise SeesysError(f"no rendered sequences (metadata.json + rgb.txt) under {root}")
    return folders


def _rgb_files(folder: Path) -> list[Path]:
    lines = (folder / "rgb.txt").read_text().splitlines()
    return [folder / line.split()[1] for line in lines if line.strip() and not line.startswith("#")]


def measure(folders: list[Path], stride: int) -> pd.DataFrame:
    """The image features of every ``stride``-th frame of each sequence."""
    rows = []
    reference, defaults = load_monitor_config().reference_camera, load_camera_config().files
    for folder in folders:
        meta = json.loads((folder / "metadata.json").read_text())
        normalisation = CameraNormalisation(reference, folder_calibration(folder, defaults).intrinsics)
        for path in _rgb_files(folder)[::stride]:
            gray = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if gray is None or gray.ndim != 2:
                raise SeesysError(f"{path}: not an 8-bit gray image")
            feats = image_features(gray, reference_scale(gray, normalisation))
            rows.append(
                {
                    "environment": meta["environment"],
                    "motion_group": meta["motion_group"],
                    "sequence": folder.name,
                    **{k: getattr(feats, k) for k in FEATURES},
                }
            )
    return pd.DataFrame(rows)


def summarise(frames: pd.DataFrame) -> pd.DataFrame:
    """Median, 10th and 90th percentile of each feature per environment (ordered by median brightness)."""
    grouped = frames.groupby("environment")[list(FEATURES)]
    table = pd.concat({"median": grouped.median(), "p10": grouped.quantile(0.1), "p90": grouped.quantile(0.9)}, axis=1)
    table.columns = [f"{feat}_{stat}" for stat, feat in table.columns]
    table["frames"] = grouped.size()
    return table.sort_values("brightness_median")


def diversity_report(root: Path, stride: int) -> DiversityReport:
    frames = measure(find_sequences(root), stride)
    return DiversityReport(frames, summarise(frames))


def write_report(report: DiversityReport, out: Path) -> list[Path]:
    """``diversity_frames.csv``, ``diversity.csv``, ``diversity.md`` and ``diversity.png`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    report.frames.to_csv(out / "diversity_frames.csv", index=False)
    report.summary.to_csv(out / "diversity.csv", float_format="%.4f")
    (out / "diversity.md").write_text(markdown_table(report.summary))
    order = list(report.summary.index)
    fig, axes = plt.subplots(1, len(FEATURES), figsize=(4 * len(FEATURES), 0.35 * len(order) + 1.5), sharey=True)
    for ax, feat in zip(axes, FEATURES):
        data = [report.frames.loc[report.frames.environment == env, feat].to_numpy() for env in order]
        ax.boxplot(data, vert=False, tick_labels=order, showfliers=False, whis=(5, 95))
        ax.set_xlabel(feat + (" (log)" if feat == "laplacian" else ""))
        if feat == "laplacian":
            ax.set_xscale("log")
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle("Per-environment image statistics of the rendered frames (boxes: quartiles, whiskers: 5-95 %)")
    fig.tight_layout()
    fig.savefig(out / "diversity.png", dpi=120)
    plt.close(fig)
    return [out / name for name in ("diversity.csv", "diversity.md", "diversity.png", "diversity_frames.csv")]


def markdown_table(summary: pd.DataFrame) -> str:
    """The summary as a Markdown table: median [p10–p90] per feature and environment, then the spread of the
    medians across environments."""
    lines = ["| environment | frames | " + " | ".join(FEATURES) + " |", "|---|---|" + "---|" * len(FEATURES)]
    for env, row in summary.iterrows():
        cells = [_cell(row, feat) for feat in FEATURES]
        lines.append(f"| {env} | {int(row['frames'])} | " + " | ".join(cells) + " |")
    spread = [f"{summary[f'{feat}_median'].min():.3g}–{summary[f'{feat}_median'].max():.3g}" for feat in FEATURES]
    lines.append("| **range of medians** | | " + " | ".join(spread) + " |")
    return "\n".join(lines) + "\n"


def _cell(row: pd.Series, feat: str) -> str:
    return f"{row[f'{feat}_median']:.3g} [{row[f'{feat}_p10']:.3g}–{row[f'{feat}_p90']:.3g}]"
