"""Label report of a dataset (paper §5.2 and Fig. 2): how the labelled errors are spread, checked against the
label-spread targets for a batch of RGB-D runs (``[targets]`` of configs/dataset.toml), and how strongly each
RTS window feature follows the error.

- Label figures use every frame of every run (``frames.csv``): median, p90, p99, the shares above the advisory
  thresholds, the share of frames tracked (:class:`seesys.core.labels.LabelSummary`), per mode, environment and
  motion group.
- Correlations use the model's samples (usable windows only): each RTS channel summarised over the 30-row
  window by its mean, minimum, maximum and standard deviation (NaN rows ignored), Spearman's ρ against the
  end frame's label (scipy).
- Per camera model of the renderer: the label figures, and the correlation of the depth channels' window
  features with the label within each camera model's samples (a channel that only tells the cameras apart shows
  no correlation within one camera; one that follows the error within each does).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from estimator.dataset.config import ReportConfig, TargetConfig
from estimator.dataset.store import DatasetError, DatasetReader
from estimator.deepsee.yardsticks import partial_spearman
from seesys.core import rts_schema
from seesys.core.labels import LabelStatus, LabelSummary
from seesys.core.motion import translation_spread
from seesys.core.units import MM_PER_M

matplotlib.use("Agg")
import matplotlib.pyplot as plt

WINDOW_STATISTICS: dict[str, Callable[..., np.ndarray]] = {
    "mean": np.nanmean,
    "min": np.nanmin,
    "max": np.nanmax,
    "std": np.nanstd,
    # The window end's own value: the frame the label is of (the second opinion's disagreement spans the label's
    # frames there, and its window mean smears six hops over them).
    "end": lambda values, axis: np.take(values, -1, axis=axis),
}
REPORT_MD = "label_report.md"
HISTOGRAM_PNG = "label_histogram.png"
CORRELATION_PNG = "feature_correlations.png"
CORRELATION_CSV = "feature_correlations.csv"
SUMMARY_CSV = "label_summary.csv"
ACCEPTANCE_MODE = "rgbd"


@dataclass(frozen=True)
class TargetCheck:
    name: str
    value: float
    target: str
    met: bool


def window_features(rts: np.ndarray, channels: list[int] | None = None) -> pd.DataFrame:
    """Per sample, each channel's (or each of the ``channels`` columns') mean/min/max/std over its raw RTS window
    (N, T, C) and its value at the window's end (``<channel>_<statistic>``)."""
    columns = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a channel NaN over a whole window gives NaN, as wanted
        for c in range(rts_schema.NUM_CHANNELS) if channels is None else channels:
            name = rts_schema.CHANNEL_NAMES[c]
            for stat, function in WINDOW_STATISTICS.items():
                columns[f"{name}_{stat}"] = function(rts[:, :, c], axis=1) if len(rts) else np.zeros(0)
    return pd.DataFrame(columns)


def window_motion(rts: np.ndarray) -> np.ndarray:
    """Per sample, the motion yardstick's statistic of its raw RTS window (``seesys.core.motion``: the spread of the
    relative translation, m/frame); NaN where a frame of the window has no pose."""
    columns = [rts_schema.index_of(name) for name in rts_schema.TRANSLATION_CHANNELS]
    return translation_spread(rts[:, :, columns]) if len(rts) else np.zeros(0)


def feature_correlations(
    features: pd.DataFrame, errors: np.ndarray, min_samples: int, motion: np.ndarray | None = None
) -> pd.DataFrame:
    """Spearman ρ (and p-value, sample count) of each feature against the errors, strongest first; with the windows'
    ``motion`` statistic also the partial Spearman ρ given it (how much of the feature's ranking of the label is not
    the motion's), on the samples where the motion is known."""
    rows = []
    for name in features.columns:
        x = features[name].to_numpy(float)
        keep = np.isfinite(x) & np.isfinite(errors)
        if keep.sum() < min_samples or np.ptp(x[keep]) == 0:
            continue
        result = spearmanr(x[keep], errors[keep])
        partial = float("nan")
        if motion is not None:
            known = keep & np.isfinite(motion)
            if known.sum() >= min_samples:
                partial = partial_spearman(x[known], errors[known], motion[known])
        rows.append((name, float(result.statistic), partial, float(result.pvalue), int(keep.sum())))
    table = pd.DataFrame(rows, columns=["feature", "spearman_rho", "partial_rho_given_motion", "p_value", "samples"])
    return table.reindex(table.spearman_rho.abs().sort_values(ascending=False).index).reset_index(drop=True)


def summary_table(frames: pd.DataFrame, by: list[str], thresholds_m: tuple[float, ...]) -> pd.DataFrame:
    """LabelSummary per group of ``frames`` (per-frame label rows with run metadata), in millimetres."""
    rows = []
    for key, group in frames.groupby(by, sort=True):
        s = LabelSummary.of(group, thresholds_m)
        row = dict(zip(by, key if isinstance(key, tuple) else (key,)))
        row.update(
            runs=group.run.nunique(),
            frames=s.frames,
            labelled=s.labelled,
            tracked_pct=100 * s.tracked_fraction,
            median_mm=MM_PER_M * s.median_m,
            p90_mm=MM_PER_M * s.p90_m,
            p99_mm=MM_PER_M * s.p99_m,
            max_mm=MM_PER_M * s.max_m,
        )
        for t in thresholds_m:
            row[f"above_{MM_PER_M * t:g}mm_pct"] = 100 * s.fraction_above[t]
        rows.append(row)
    return pd.DataFrame(rows)


def check_targets(summary: LabelSummary, best_rho: float, targets: TargetConfig) -> list[TargetCheck]:
    """The issue's acceptance figures for a batch of RGB-D runs, each against its target."""

    def within(value: float, bounds: tuple[float, float]) -> bool:
        return bool(bounds[0] <= value <= bounds[1])

    mm = MM_PER_M
    above = summary.fraction_above.get(0.012, float("nan"))
    return [
        TargetCheck(
            "median (mm)",
            mm * summary.median_m,
            f"{mm * targets.median_m[0]:g}–{mm * targets.median_m[1]:g}",
            within(summary.median_m, targets.median_m),
        ),
        TargetCheck(
            "p90 (mm)",
            mm * summary.p90_m,
            f"{mm * targets.p90_m[0]:g}–{mm * targets.p90_m[1]:g}",
            within(summary.p90_m, targets.p90_m),
        ),
        TargetCheck(
            "p99 (mm)", mm * summary.p99_m, f"≥ {mm * targets.p99_min_m:g}", bool(summary.p99_m >= targets.p99_min_m)
        ),
        TargetCheck(
            "frames > 12 mm (%)",
            100 * above,
            f"{100 * targets.above_12mm_fraction[0]:g}–{100 * targets.above_12mm_fraction[1]:g}",
            within(above, targets.above_12mm_fraction),
        ),
        TargetCheck(
            "frames tracked (%)",
            100 * summary.tracked_fraction,
            f"≥ {100 * targets.tracked_min_fraction:g}",
            bool(summary.tracked_fraction >= targets.tracked_min_fraction),
        ),
        TargetCheck(
            "best Spearman ρ, absolute",
            abs(best_rho),
            f"≥ {targets.spearman_min_abs:g}",
            bool(abs(best_rho) >= targets.spearman_min_abs),
        ),
    ]


@dataclass(frozen=True)
class ModeReport:
    """One SLAM mode's label figures; ``features`` and ``errors`` are its usable samples (for the plots)."""

    mode: str
    summary: LabelSummary
    correlations: pd.DataFrame
    checks: list[TargetCheck]
    features: pd.DataFrame
    errors: np.ndarray


@dataclass(frozen=True)
class LabelReport:
    modes: list[ModeReport]
    by_camera: pd.DataFrame  # label figures per mode and camera model
    depth_correlations: pd.DataFrame  # the depth channels' window features against the label, per camera model
    by_group: pd.DataFrame
    by_trial: pd.DataFrame  # one batch = one trial of every sequence
    frames: pd.DataFrame  # per-frame labels of every run

    def main_mode(self) -> ModeReport:
        """The RGB-D report when there is one (the acceptance batch), else the first mode's."""
        return next((m for m in self.modes if m.mode == ACCEPTANCE_MODE), self.modes[0])


def _labelled_errors(frames: pd.DataFrame) -> np.ndarray:
    return frames.loc[frames.status == LabelStatus.LABELLED.value, "error_m"].to_numpy(float)


def label_report(roots: list[Path], config: ReportConfig, targets: TargetConfig) -> LabelReport:
    reader = DatasetReader(roots, usable_only=True)
    frames = DatasetReader(roots).frame_labels()
    if frames.empty:
        raise DatasetError(f"no completed runs in {', '.join(map(str, roots))}")
    windows = reader.rts_windows()
    features, motion = window_features(windows), window_motion(windows)
    errors = reader.index.error_m.to_numpy(float)
    modes = []
    for mode, mode_frames in frames.groupby("mode", sort=True):
        in_mode = (reader.index["mode"] == mode).to_numpy()
        mode_features = features[in_mode].reset_index(drop=True)
        correlations = feature_correlations(mode_features, errors[in_mode], config.min_samples, motion[in_mode])
        summary = LabelSummary.of(mode_frames, config.thresholds_m)
        best = float(correlations.spearman_rho.iloc[0]) if len(correlations) else float("nan")
        modes.append(
            ModeReport(
                mode, summary, correlations, check_targets(summary, best, targets), mode_features, errors[in_mode]
            )
        )
    by_camera = summary_table(frames, ["mode", "camera_model"], config.thresholds_m)
    by_group = summary_table(frames, ["mode", "camera_model", "environment", "motion_group"], config.thresholds_m)
    by_trial = summary_table(frames, ["mode", "trial"], config.thresholds_m)
    return LabelReport(
        modes,
        by_camera,
        depth_by_camera(features, errors, reader.index, config.min_samples),
        by_group,
        by_trial,
        frames,
    )


def depth_by_camera(features: pd.DataFrame, errors: np.ndarray, index: pd.DataFrame, min_samples: int) -> pd.DataFrame:
    """Spearman ρ of the depth channels' window features against the label within each mode and camera model."""
    depth = rts_schema.channel_names("depth")
    columns = [f for f in features.columns if f.rsplit("_", 1)[0] in depth]
    tables = []
    for (mode, camera), group in index.groupby(["mode", "camera_model"], sort=True):
        rows = group.index.to_numpy()
        table = feature_correlations(features.loc[rows, columns].reset_index(drop=True), errors[rows], min_samples)
        tables.append(table.assign(mode=mode, camera_model=camera))
    return (
        pd.concat(tables, ignore_index=True)
        if tables
        else pd.DataFrame(columns=["feature", "spearman_rho", "p_value", "samples", "mode", "camera_model"])
    )


def _markdown_table(table: pd.DataFrame, digits: int = 1) -> str:
    def cell(v) -> str:
        return f"{v:.{digits}f}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join(lines)


def render_markdown(report: LabelReport, config: ReportConfig) -> str:
    out = ["# Label report", ""]
    for m in report.modes:
        s = m.summary
        out += [f"## {m.mode}: {s.labelled} labelled of {s.frames} frames", ""]
        if m.mode == ACCEPTANCE_MODE:
            checks = pd.DataFrame(
                [(c.name, c.value, c.target, "yes" if c.met else "NO") for c in m.checks],
                columns=["figure", "value", "target", "met"],
            )
            out += [
                "Acceptance figures for this batch of RGB-D runs (10-frame translation RPE, labelled frames):",
                "",
                _markdown_table(checks),
                "",
            ]
        else:
            out += [
                f"median {MM_PER_M * s.median_m:.1f} mm, p90 {MM_PER_M * s.p90_m:.1f} mm, "
                f"p99 {MM_PER_M * s.p99_m:.1f} mm, tracked {100 * s.tracked_fraction:.1f} %, "
                + ", ".join(f"> {MM_PER_M * t:g} mm {100 * v:.1f} %" for t, v in s.fraction_above.items()),
                "",
            ]
        top = m.correlations.head(config.top_features)
        out += [
            f"RTS window features with the largest |Spearman ρ| against the label ({m.mode}, usable samples), and "
            "their partial ρ given the window's motion statistic (the spread of its relative translation):",
            "",
            _markdown_table(top[["feature", "spearman_rho", "partial_rho_given_motion", "samples"]], digits=3),
            "",
        ]
    out += [
        "## Per camera model",
        "",
        "Label figures per mode and camera model of the renderer:",
        "",
        _markdown_table(report.by_camera),
        "",
    ]
    if len(report.depth_correlations):
        top = (
            report.depth_correlations.assign(strength=report.depth_correlations.spearman_rho.abs())
            .sort_values(["mode", "camera_model", "strength"], ascending=[True, True, False])
            .groupby(["mode", "camera_model"])
            .head(config.top_features)
        )
        out += [
            "Depth channels' window features against the label within each camera model (usable samples; "
            "monocular runs have no depth):",
            "",
            _markdown_table(top[["mode", "camera_model", "feature", "spearman_rho", "samples"]], digits=3),
            "",
        ]
    out += [
        "## Per mode and trial (each trial of every sequence is one batch)",
        "",
        _markdown_table(report.by_trial),
        "",
    ]
    out += ["## Per mode, camera model, environment and motion group", "", _markdown_table(report.by_group), ""]
    return "\n".join(out)


def plot_histogram(frames: pd.DataFrame, config: ReportConfig, path: Path) -> None:
    """Histogram of the labels on a log x axis, one line per mode, with the advisory thresholds."""
    bins = np.geomspace(*config.histogram_range_m, config.histogram_bins + 1)
    fig, ax = plt.subplots(figsize=(7, 4))
    for mode, group in frames.groupby("mode", sort=True):
        errors = _labelled_errors(group)
        ax.hist(
            np.clip(errors, bins[0], bins[-1]),
            # matplotlib's stub types bins as a Sequence, but hist takes the edges as an array (np.histogram does)
            bins=bins,  # type: ignore[arg-type]
            histtype="step",
            lw=1.5,
            label=f"{mode} ({len(errors)} frames)",
        )
    for t in config.thresholds_m:
        ax.axvline(t, color="gray", ls="--", lw=1)
        ax.text(t, ax.get_ylim()[1] * 0.95, f" {MM_PER_M * t:g} mm", color="gray", va="top")
    ax.set_xscale("log")
    ax.set_xlabel("10-frame translation RPE (m)")
    ax.set_ylabel("frames")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_correlations(mode: ModeReport, config: ReportConfig, path: Path) -> None:
    """Paper Fig. 2: the label against the window features most correlated with it (log y), usable samples."""
    top = mode.correlations.head(config.scatter_plots)
    cols = 3
    rows = max(1, -(-len(top) // cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3.2 * rows), squeeze=False)
    for ax, (name, rho) in zip(axes.ravel(), zip(top.feature, top.spearman_rho)):
        ax.scatter(mode.features[name], mode.errors, s=4, alpha=0.4)
        ax.set_yscale("log")
        ax.set_title(f"{name}  ρ = {rho:+.2f}", fontsize=9)
        ax.set_ylabel("error (m)")
    for ax in axes.ravel()[len(top) :]:
        ax.axis("off")
    fig.suptitle(f"{mode.mode}: label vs RTS window features")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(roots: list[Path], config: ReportConfig, targets: TargetConfig, out: Path) -> LabelReport:
    """Compute the report and write ``label_report.md``, the CSV tables and the PNG plots under ``out``."""
    report = label_report(roots, config, targets)
    out.mkdir(parents=True, exist_ok=True)
    (out / REPORT_MD).write_text(render_markdown(report, config))
    report.by_group.to_csv(out / SUMMARY_CSV, index=False)
    pd.concat([m.correlations.assign(mode=m.mode) for m in report.modes]).to_csv(out / CORRELATION_CSV, index=False)
    plot_histogram(report.frames, config, out / HISTOGRAM_PNG)
    plot_correlations(report.main_mode(), config, out / CORRELATION_PNG)
    return report
