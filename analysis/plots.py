"""The study's figures (matplotlib, PNG): per-condition box/strip plots, trajectories coloured by the estimated
error, and error over time with the audio pulses and the operator's events.

Times: SLAM poses and RPE pairs are on the camera clock; the advisory's buffers and the operator's events are in
Unix time. The estimate log holds both for each estimate (receipt time, frame time), and the median difference
maps Unix time onto the camera clock (it includes the estimate's latency, tens of milliseconds, which is
invisible at the scale of a task). Without an estimate log both clocks are taken to be the same, as they are
with a live RealSense camera.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from analysis.config import AnalysisConfig, Variable
from seesys.core.trajectory import TrajectoryError
from seesys.io.logfiles import read_csv_log
from seesys.io.trajectory_files import read_tum
from study.estimates import read_estimate_log, wall_to_camera_offset
from study.sessions import StudyData, read_events

ADVISORY_CSV = "advisory.csv"


def box_strip(table: pd.DataFrame, variable: Variable, conditions: list[str], out: Path) -> Path:
    """Box plot per condition with every participant as a jittered point."""
    fig, ax = plt.subplots(figsize=(1.8 + 1.3 * len(conditions), 3.6))
    values = [table.loc[table.condition == c, variable.column].dropna().to_numpy() * variable.scale for c in conditions]
    ax.boxplot(values, tick_labels=conditions, showfliers=False, widths=0.5)
    rng = np.random.default_rng(0)
    for i, v in enumerate(values, start=1):
        ax.scatter(i + rng.uniform(-0.12, 0.12, len(v)), v, s=18, alpha=0.8, zorder=3)
    ax.set_ylabel(variable.title)
    ax.set_title(f"{variable.label} per condition")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    path = out / f"box_{variable.column}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _estimated_error_at(attempt: Path, times: np.ndarray, max_gap_s: float = 0.5) -> np.ndarray:
    """The estimate of the frame nearest each time (sorted), NaN where none is within ``max_gap_s``."""
    log = read_estimate_log(attempt)
    if log.empty:
        return np.full(len(times), np.nan)
    merged = pd.merge_asof(
        pd.DataFrame({"timestamp": np.asarray(times, float)}),
        log[["timestamp", "error_m"]].astype(float).sort_values("timestamp"),
        on="timestamp",
        direction="nearest",
        tolerance=max_gap_s,
    )
    return merged.error_m.to_numpy()


def _participants_to_plot(data: StudyData, condition: str, cfg: AnalysisConfig) -> list[tuple[str, list]]:
    chosen = [(p, a) for (p, c), a in sorted(data.attempts.items()) if c == condition]
    return chosen[: cfg.plots_per_condition]


def trajectories(data: StudyData, condition: str, cfg: AnalysisConfig, out: Path) -> Path | None:
    """Top views (the two axes of largest extent) of participants' trajectories, coloured by the estimated error
    (cm) on one colour scale for the whole figure."""
    chosen = _participants_to_plot(data, condition, cfg)
    if not chosen:
        return None
    drawn = []
    for participant, attempts in chosen:
        for a in attempts:
            try:
                poses = read_tum(a.folder / "trajectory.tum")
            except TrajectoryError:
                continue
            if len(poses) > 1:
                drawn.append((participant, poses, _estimated_error_at(a.folder, poses.timestamps) * 100))
    errors = np.concatenate([e for _, _, e in drawn]) if drawn else np.zeros(0)
    finite = errors[np.isfinite(errors)]
    norm = plt.Normalize(*(np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0)))
    fig, axes = plt.subplots(
        1, len(chosen), figsize=(3.4 * len(chosen) + 1.2, 3.8), squeeze=False, layout="constrained"
    )
    panel = {participant: ax for ax, (participant, _) in zip(axes[0], chosen)}
    for participant, poses, error_cm in drawn:
        ax = panel[participant]
        u, v = np.argsort(np.ptp(poses.positions, axis=0))[::-1][:2]
        ax.plot(poses.positions[:, u], poses.positions[:, v], color="0.8", lw=0.8, zorder=1)
        ax.scatter(
            poses.positions[:, u],
            poses.positions[:, v],
            c=error_cm,
            s=6,
            cmap="viridis",
            norm=norm,
            zorder=2,
            plotnonfinite=True,
        )
    for participant, ax in panel.items():
        ax.set_title(participant)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("m")
    fig.suptitle(f"Trajectories, {condition}: coloured by estimated error")
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap="viridis"), ax=axes[0].tolist(), label="estimated error (cm)")
    path = out / f"trajectories_{condition}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def error_over_time(data: StudyData, condition: str, cfg: AnalysisConfig, out: Path) -> Path | None:
    """Tracking error (RPE pairs) and estimated error over time, with audio pulses and events."""
    chosen = _participants_to_plot(data, condition, cfg)
    if not chosen:
        return None
    fig, axes = plt.subplots(len(chosen), 1, figsize=(8, 2.2 * len(chosen)), squeeze=False, sharex=False)
    for ax, (participant, attempts) in zip(axes[:, 0], chosen):
        for a in attempts:
            if a.rpe.timestamps.size == 0:
                continue
            t0 = a.rpe.timestamps[0]
            ax.plot(a.rpe.timestamps - t0, a.rpe.errors_m * 100, lw=0.8, label="tracking error (RPE)")
            log = read_estimate_log(a.folder)
            if not log.empty:
                ax.plot(log.timestamp - t0, log.error_m * 100, lw=0.8, alpha=0.8, label="estimated error")
            offset = wall_to_camera_offset(a.folder)
            if (a.folder / ADVISORY_CSV).exists():
                advisory = read_csv_log(a.folder / ADVISORY_CSV)
                pulses = advisory.loc[advisory.n_pulses > 0, "wall_time"] + offset - t0
                ax.vlines(
                    pulses, 0, 0.15, transform=ax.get_xaxis_transform(), colors="tab:red", lw=0.6, label="audio pulses"
                )
            for e in read_events(a.folder).itertuples():
                ax.axvline(e.time + offset - t0, color="0.4", ls=":", lw=0.8)
                ax.annotate(
                    f"{e.kind} {e.detail if isinstance(e.detail, str) else ''}".strip(),
                    (e.time + offset - t0, 0.95),
                    xycoords=("data", "axes fraction"),
                    fontsize=6,
                    rotation=90,
                    va="top",
                )
        ax.set_title(participant, fontsize=9)
        ax.set_ylabel("cm")
        handles, labels = ax.get_legend_handles_labels()
        unique = dict(zip(labels, handles))
        if unique:
            ax.legend(unique.values(), unique.keys(), fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time from the first pair (s)")
    fig.suptitle(f"Error over time, {condition}")
    fig.tight_layout()
    path = out / f"error_over_time_{condition}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def tradeoff(table: pd.DataFrame, conditions: list[str], x: Variable, y: Variable, out: Path) -> Path | None:
    """Time on task against tracking error, one point per participant and condition, the conditions' means as
    large markers, and the least-squares line through the points of the conditions that sound without information
    (``none`` and ``yoked``, where present): an advisory that only slows the operator down lies on that line."""
    data = table.dropna(subset=[x.column, y.column])
    if data.empty:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for i, condition in enumerate(conditions):
        rows = data[data.condition == condition]
        if rows.empty:
            continue
        xs, ys = rows[x.column].to_numpy(float) * x.scale, rows[y.column].to_numpy(float) * y.scale
        colour = f"C{i}"
        ax.scatter(xs, ys, s=22, alpha=0.7, color=colour, label=condition)
        ax.scatter([xs.mean()], [ys.mean()], s=140, marker="D", color=colour, edgecolor="black", zorder=4)
    pacing = data[data.condition.isin(["none", "yoked"])]
    if len(pacing) >= 3 and np.ptp(pacing[x.column].to_numpy(float)) > 0:
        px, py = pacing[x.column].to_numpy(float) * x.scale, pacing[y.column].to_numpy(float) * y.scale
        slope, intercept = np.polyfit(px, py, 1)
        grid = np.linspace(data[x.column].min() * x.scale, data[x.column].max() * x.scale, 50)
        ax.plot(grid, slope * grid + intercept, "k--", lw=1, label="pacing alone (fit to none and yoked)")
    ax.set_xlabel(x.title)
    ax.set_ylabel(y.title)
    ax.set_title(f"{y.label} against {x.label.lower()} (one point per participant and condition)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / f"tradeoff_{x.column}_{y.column}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
