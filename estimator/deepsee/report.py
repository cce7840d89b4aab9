"""The evaluation report: Table 3's layout (RMSE and MAPE of every row, mean ± std over the rounds), with the
same RMSE on the paper's label range, Spearman ρ and the advisory figures (with the ordinal head's own, as more
columns, in a set where some row has a head), and the yardsticks that do not reward the base rate (κ, AURG, AUSE,
partial ρ given motion, with bootstrap intervals over runs), for each evaluation set; the reference rows (constant,
always the top class, motion only) and the ceiling (another SLAM trial) beside the models; which schedule and
hardware made each row; DeepSEE against the targets of ``[targets]`` in configs/estimator.toml; the median ratio per
camera model; and the figures (estimate and truth over time on test sequences, scatter, advisory class confusion,
the head's reliability diagram)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from estimator.dataset.splits import TEST_TRAJECTORIES
from estimator.deepsee.config import EstimatorConfig, TargetsConfig
from estimator.deepsee.evaluate import Evaluation, round_folder
from estimator.deepsee.metrics import CM_PER_M, advisory_bins, confusion
from estimator.deepsee.references import (
    CEILING,
    CEILING_ROW,
    CONSTANT,
    MOTION_ISOTONIC,
    REFERENCE_ROWS,
    ReferenceRow,
)
from estimator.deepsee.rows import DEEPSEE, LSTM, RANDOM_FOREST, ROWS, Row
from estimator.deepsee.run_folder import CONFIG_JSON, HARDWARE_JSON
from estimator.deepsee.yardsticks import WITH_INTERVALS
from seesys.core.equation2 import PulseSettings

REPORT_MD = "estimator_report.md"
SCORES_CSV = "scores.csv"
PREDICTIONS_CSV = "predictions.csv"
TIMESERIES_PNG = "estimator-timeseries.png"
SCATTER_PNG = "estimator-scatter.png"
CONFUSION_PNG = "estimator-advisory-confusion.png"
RELIABILITY_PNG = "estimator-head-reliability.png"
CAMERAS_CSV = "camera_ratios.csv"
CALIBRATION_CSV = "head_calibration.csv"
CHANNELS_CSV = "channels.csv"
DIFFERENCES_CSV = "differences.csv"
# (column, heading, format) of the Table 3 layout; the yardsticks of WITH_INTERVALS show their interval too.
COLUMNS = (
    ("rmse_cm", "RMSE (cm)", "{:.3f}"),
    ("rmse_paper_range_cm", "RMSE 1 mm–2 cm (cm)", "{:.3f}"),
    ("mape", "MAPE", "{:.3f}"),
    ("spearman", "Spearman ρ", "{:.2f}"),
    ("partial_spearman", "partial ρ given motion", "{:.2f}"),
    ("kappa", "κ (quadratic)", "{:.2f}"),
    ("aurg", "AURG", "{:.2f}"),
    ("aurg_capped", "AURG to 12 mm", "{:.2f}"),
    ("ause", "AUSE", "{:.2f}"),
    ("agreement", "advisory agreement", "{:.2f}"),
    ("recall_large", "recall ≥ 12 mm", "{:.2f}"),
    ("median_ratio", "median est. / true", "{:.2f}"),
)
# The ordinal head's columns, shown where some row of the set has a head (estimator/deepsee/metrics.py).
HEAD_COLUMNS = (
    ("head_agreement", "head agreement", "{:.2f}"),
    ("head_kappa", "head κ", "{:.2f}"),
    ("head_recall_large", "head recall ≥ 12 mm", "{:.2f}"),
    ("head_brier", "head Brier", "{:.3f}"),
    ("head_ece", "head ECE", "{:.3f}"),
)
IMPROVEMENT_METRICS = {"rmse_cm": "RMSE", "rmse_paper_range_cm": "RMSE 1 mm–2 cm"}  # score column: its name
# The rows of a set's table, in order: what every estimate must beat, the trained rows, the ceiling.
TABLE_ROWS: tuple[Row | ReferenceRow, ...] = (*REFERENCE_ROWS, *ROWS, CEILING_ROW)


def improvement_targets(targets: TargetsConfig) -> dict[str, float]:
    """DeepSEE's RMSE gain over each baseline that ``[targets]`` asks for."""
    return {RANDOM_FOREST: targets.rmse_gain_over_random_forest, LSTM: targets.rmse_gain_over_lstm}


def _cell(values: pd.Series, fmt: str, low: pd.Series | None = None, high: pd.Series | None = None) -> str:
    """One round's value, or the mean ± std over rounds; with ``low`` and ``high``, the bootstrap interval in
    brackets (over several rounds: from the lowest round's low to the highest round's high)."""
    values = values.dropna()
    if values.empty:
        return "–"
    text = (
        fmt.format(values.iloc[0])
        if len(values) == 1
        else f"{fmt.format(values.mean())} ± {fmt.format(values.std(ddof=1))}"
    )
    if low is not None and high is not None and low.notna().any() and high.notna().any():
        text += f" [{fmt.format(low.min())}, {fmt.format(high.max())}]"
    return text


def _provenance(runs: Path, row: str) -> str:
    """Schedule and hardware of the row's round-0 run."""
    folder = round_folder(runs, 0) / row
    try:
        schedule = json.loads((folder / CONFIG_JSON).read_text())["schedule_name"]
        hardware = json.loads((folder / HARDWARE_JSON).read_text())[-1]
    except (OSError, ValueError, KeyError, IndexError):
        return "–"
    where = hardware.get("gpu") or f"{hardware.get('cpu_count')}-core CPU"
    return f"{schedule}, {hardware['device']} ({where})"


def _columns(part: pd.DataFrame) -> tuple[tuple[str, str, str], ...]:
    """Table 3's columns, and the head's where a row of ``part`` has head scores."""
    with_head = all(c in part and part[c].notna().any() for c, _, _ in HEAD_COLUMNS)
    return COLUMNS + HEAD_COLUMNS if with_head else COLUMNS


def table(scores: pd.DataFrame, set_name: str, runs: Path) -> list[str]:
    """The set's rows: the reference rows, the trained rows, the ceiling, each where it was judged."""
    part = scores[scores.set == set_name]
    columns = _columns(part)
    headings = " | ".join(h for _, h, _ in columns)
    lines = [
        f"| Category | Method | {headings} | windows | runs | rounds | schedule, device |",
        "|---" * (len(columns) + 6) + "|",
    ]
    for row in TABLE_ROWS:
        rows = part[part.row == row.name]
        if rows.empty:
            continue
        cells = [
            _cell(rows[c], f, rows.get(f"{c}_low"), rows.get(f"{c}_high")) if c in WITH_INTERVALS else _cell(rows[c], f)
            for c, _, f in columns
        ]
        provenance = (
            _provenance(runs, row.name)
            if row in ROWS
            else "fitted on the round's training data"
            if (row in REFERENCE_ROWS)
            else "–"
        )
        low, high = int(rows.runs.min()), int(rows.runs.max())
        runs_cell = str(low) if low == high else f"{low}–{high}"
        lines.append(
            f"| {row.category} | {row.label} | "
            + " | ".join(cells)
            + f" | {int(rows.windows.mean())} | {runs_cell} | {len(rows)} | {provenance} |"
        )
    return lines


def improvements(scores: pd.DataFrame, set_name: str, targets: TargetsConfig) -> list[str]:
    """DeepSEE's RMSE, and its RMSE on the paper's label range (the one the paper's gains are on: its labels were
    clipped to that range), against each baseline's: the gain of the mean over the rounds and each round's own,
    against ``targets``."""
    part = scores[scores.set == set_name]
    lines = []
    for column, metric in IMPROVEMENT_METRICS.items():
        by_round = part.pivot_table(index="round", columns="row", values=column)
        for baseline, target in improvement_targets(targets).items():
            if DEEPSEE not in by_round or baseline not in by_round:
                continue
            both = by_round[[DEEPSEE, baseline]].dropna()
            if both.empty:
                continue
            gain = 1 - both[DEEPSEE].mean() / both[baseline].mean()
            gains = 1 - both[DEEPSEE] / both[baseline]
            verdict = "reached" if gain >= target else "NOT reached"
            per_round = ", ".join(f"{100 * g:+.0f} %" for g in gains)
            lines.append(
                f"- DeepSEE vs {baseline}, {metric}: {100 * gain:+.1f} % lower (mean over {len(both)} "
                f"rounds; target ≥ {100 * target:.0f} %: {verdict}; per round {per_round}, "
                f"{int((gains >= target).sum())} of {len(both)} reach it)"
            )
    return lines


def _verdict(value: float, bound: float, above: bool) -> str:
    if not np.isfinite(value) or not np.isfinite(bound):
        return "not judged"
    return "met" if (value >= bound if above else value <= bound) else "NOT met"


def target_lines(scores: pd.DataFrame, set_name: str, targets: TargetsConfig, row: str = DEEPSEE) -> list[str]:
    """``row`` against ``targets`` on one set, means over the rounds, each target stated against the reference
    row or the ceiling it is relative to (the ceiling's targets are not judged where the set has no ceiling)."""
    part = scores[scores.set == set_name]
    mean = part.groupby("row").mean(numeric_only=True)
    if row not in mean.index:
        return []
    model = mean.loc[row]

    def of(name: str, column: str) -> float:
        return float(mean.loc[name, column]) if name in mean.index else float("nan")

    ceiling_kappa, motion_kappa = of(CEILING, "kappa"), of(MOTION_ISOTONIC, "kappa")
    ceiling_recall, motion_aurg = of(CEILING, "recall_large"), of(MOTION_ISOTONIC, "aurg")
    constant = of(CONSTANT, "agreement")
    ratio = model.median_ratio
    checks = [
        (
            f"κ {model.kappa:.2f} ≥ {targets.kappa_share_of_ceiling:g} × the ceiling's {ceiling_kappa:.2f}",
            _verdict(model.kappa, targets.kappa_share_of_ceiling * ceiling_kappa, True),
        ),
        (
            f"κ {model.kappa:.2f} ≥ the motion-only row's {motion_kappa:.2f} + {targets.kappa_over_motion:g}",
            _verdict(model.kappa, motion_kappa + targets.kappa_over_motion, True),
        ),
        (
            f"AURG {model.aurg:.2f} ≥ the motion-only row's {motion_aurg:.2f} + {targets.aurg_over_motion:g}",
            _verdict(model.aurg, motion_aurg + targets.aurg_over_motion, True),
        ),
        (
            f"agreement {model.agreement:.2f} ≥ the constant class's {constant:.2f} + "
            f"{targets.agreement_over_constant:g}",
            _verdict(model.agreement, constant + targets.agreement_over_constant, True),
        ),
        (
            f"recall ≥ 12 mm {model.recall_large:.2f} ≥ {targets.recall_share_of_ceiling:g} × the ceiling's "
            f"{ceiling_recall:.2f}",
            _verdict(model.recall_large, targets.recall_share_of_ceiling * ceiling_recall, True),
        ),
        (
            f"median ratio {ratio:.2f} within ×{targets.median_ratio_within:g}",
            _verdict(max(ratio, 1 / ratio) if ratio > 0 else float("nan"), targets.median_ratio_within, False),
        ),
    ]
    rounds = int((part.row == row).sum())
    heading = f"- {row} against the targets (configs/estimator.toml [targets]; mean over {rounds} rounds):"
    return [heading] + [f"  - {text}: {verdict}" for text, verdict in checks]


def camera_table(cameras: pd.DataFrame, set_name: str) -> list[str]:
    """Median estimate / median truth per camera model of the set's runs, per row (mean over rounds)."""
    part = cameras[cameras.set == set_name]
    if part.empty:
        return []
    ratios = part.pivot_table(index="row", columns="camera_model", values="median_ratio", aggfunc="mean")
    order = [r.name for r in TABLE_ROWS if r.name in ratios.index]
    names = list(ratios.columns)
    lines = [
        "Median estimate / median truth per camera model (mean over rounds):",
        "",
        "| row | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for name in order:
        lines.append(f"| {name} | " + " | ".join("–" if pd.isna(v) else f"{v:.2f}" for v in ratios.loc[name]) + " |")
    return lines + [""]


def difference_lines(differences: pd.DataFrame, set_name: str) -> list[str]:
    """Each trained row against the motion-only row and the forest on the set's windows, paired run by run: the
    difference of κ, AURG and partial ρ, and its bootstrap interval over runs (over several rounds: from the lowest
    round's low to the highest round's high)."""
    part = differences[differences.set == set_name]
    if part.empty:
        return []
    lines = [
        "Paired over runs (the same resampled runs for both rows): each row minus the compared row, with the "
        f"interval of the difference ({DIFFERENCES_CSV}); an interval above 0 says the row is better on these runs:",
        "",
        "| row | minus | Δ κ | Δ AURG | Δ AURG to 12 mm | Δ partial ρ given motion |",
        "|---|---|---|---|---|---|",
    ]
    for (row, against), group in part.groupby(["row", "against"], sort=False):
        cells = [
            _cell(group[name], "{:+.2f}", group[f"{name}_low"], group[f"{name}_high"])
            for name in ("kappa", "aurg", "aurg_capped", "partial_spearman")
        ]
        lines.append(f"| {row} | {against} | " + " | ".join(cells) + " |")
    return lines + [""]


def channel_lines(channels: pd.DataFrame, set_name: str) -> list[str]:
    """The geometry channels alone on the set (estimator/deepsee/channels.py): per round, each channel's window
    feature chosen on that round's training windows, its ρ and partial ρ given motion with their intervals."""
    if "chosen" not in channels:
        return []
    part = channels[(channels.set == set_name) & channels.chosen.astype(bool)]
    if part.empty:
        return []
    lines = [
        "The geometry channels alone (each by the window feature with the largest |partial ρ| on the round's "
        f"training windows; all five features of every channel in {CHANNELS_CSV}):",
        "",
        "| round | channel | feature | windows | runs | Spearman ρ | partial ρ given motion |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in part.itertuples():
        rho, partial = (
            _cell(
                pd.Series([getattr(row, c)]),
                "{:.2f}",
                pd.Series([getattr(row, f"{c}_low")]),
                pd.Series([getattr(row, f"{c}_high")]),
            )
            for c in ("spearman", "partial_spearman")
        )
        lines.append(
            f"| {row.round} | {row.channel} | {row.feature} | {row.windows} | {row.runs} | {rho} | {partial} |"
        )
    return lines + [""]


def _plot_timeseries(predictions: pd.DataFrame, count: int, out: Path) -> Path:
    runs = list(dict.fromkeys(predictions.run))[:count]
    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 2.4 * len(runs)), squeeze=False)
    for ax, run in zip(axes[:, 0], runs):
        rows = predictions[predictions.run == run].sort_values("timestamp")
        t = rows.timestamp - rows.timestamp.min()
        ax.plot(t, CM_PER_M * rows.true_m, lw=0.8, label="true")
        ax.plot(t, CM_PER_M * rows.estimate_m, lw=0.8, label="estimate")
        ax.set_title(run, fontsize=8)
        ax.set_ylabel("error (cm)")
        ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def _plot_scatter(predictions: pd.DataFrame, rows: list[str], out: Path) -> Path:
    fig, axes = plt.subplots(1, len(rows), figsize=(4 * len(rows), 4), squeeze=False)
    for ax, name in zip(axes[0], rows):
        part = predictions[predictions.row == name]
        ax.scatter(CM_PER_M * part.true_m, CM_PER_M * part.estimate_m, s=2, alpha=0.3)
        limits = [max(1e-3, CM_PER_M * part.true_m.min()), CM_PER_M * max(part.true_m.max(), part.estimate_m.max())]
        ax.plot(limits, limits, "k--", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("true error (cm)")
        ax.set_ylabel("estimate (cm)")
        ax.set_title(name)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def _plot_confusion(matrix: np.ndarray, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(4, 3.6))
    ax.imshow(matrix, cmap="Blues")
    for (i, j), count in np.ndenumerate(matrix):
        ax.text(j, i, str(count), ha="center", va="center", fontsize=8)
    ax.set_xlabel("pulses from estimates")
    ax.set_ylabel("pulses from true errors")
    ax.set_title("Equation 2 class per 1/3 s")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def _plot_reliability(calibration: pd.DataFrame, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(4.2, 4))
    for threshold, part in calibration.groupby("threshold_m"):
        ax.plot(part.confidence, part.observed, "o-", ms=3, label=f"P(error ≥ {1000 * threshold:g} mm)")
    ax.plot([0, 1], [0, 1], "k--", lw=0.8)
    ax.set_xlabel("mean predicted probability")
    ax.set_ylabel("observed share")
    ax.set_title("head reliability")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def write_report(
    evaluation: Evaluation, config: EstimatorConfig, pulses: PulseSettings, out: Path, notes: list[str]
) -> Path:
    """Write ``estimator_report.md``, the scores and predictions CSVs and the figures into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scores, predictions = evaluation.scores, evaluation.predictions
    scores.to_csv(out / SCORES_CSV, index=False)
    predictions.to_csv(out / PREDICTIONS_CSV, index=False)
    evaluation.cameras.to_csv(out / CAMERAS_CSV, index=False)
    evaluation.calibration.to_csv(out / CALIBRATION_CSV, index=False)
    evaluation.channels.to_csv(out / CHANNELS_CSV, index=False)
    evaluation.differences.to_csv(out / DIFFERENCES_CSV, index=False)
    lines = (
        ["# DeepSEE evaluation (Table 3 layout)", ""]
        + [f"- {n}" for n in notes]
        + [
            f"- Rounds: {', '.join(str(r) for r in sorted(set(scores['round'])))}; values are mean ± std over rounds.",
            f"- RMSE 1 mm–2 cm: RMSE over the windows whose true error lies in the paper's label range "
            f"({config.evaluation.paper_range_m[0] * 1000:g}–{config.evaluation.paper_range_m[1] * 1000:g} mm); the "
            f"authors clipped their labels to it, ours are not clipped.",
            "- Advisory agreement: share of 1/3 s bins where Equation 2 gives the same pulse count from the averaged "
            "estimates as from the averaged true errors; recall ≥ 12 mm: share of bins with a true mean ≥ 12 mm whose "
            "estimated mean is also ≥ 12 mm. Head agreement, κ and recall ≥ 12 mm (where a model has an ordinal head "
            "for Equation 2's class boundaries): the same with the class the head gives from its probabilities "
            "averaged over each bin; head Brier and ECE: per window, the mean over its thresholds "
            f"({CALIBRATION_CSV} has each threshold and its reliability diagram); the forest and the LSTM have no "
            "head (–).",
            "- κ: quadratic-weighted Cohen's κ of the bins' Equation 2 classes (0 for any constant class, 1 "
            "when all are "
            "right). AURG and AUSE: the sparsification curve (windows removed largest estimate first, the mean true "
            "error of those kept, divided by the mean of all), its mean gain over a random order (AURG; 0 for a "
            "constant) and its mean gap to the order of the truth (AUSE; 0 for a perfect order). AURG to 12 mm: the "
            "same AURG with every true error from the top class boundary on counted at it, so that a few metre-scale "
            "windows (map jumps, which the motion row finds by construction) do not decide it. Partial ρ given "
            "motion: Spearman ρ of estimate and truth given the window's motion statistic (the standard deviation of "
            "its relative translation).",
            f"- Brackets: {100 * config.evaluation.confidence:g} % bootstrap interval over runs "
            f"({config.evaluation.bootstrap_resamples} resamples of whole runs; with several rounds, from the lowest "
            "round's low to the highest round's high); runs: the effective n of those intervals.",
            "- Reference rows, fitted on the round's training data only: the training bins' most frequent class "
            "(constant), always the top class, and the motion statistic mapped to an error by isotonic regression "
            "(motion only). Ceiling: the true error of another SLAM trial of the same render at the same frame, on the "
            "windows such a trial labelled; for out-of-domain sessions, another session of the same source and mode.",
            "",
        ]
    )
    for set_name in dict.fromkeys(scores.set):
        lines += [f"## {set_name}", ""] + table(scores, set_name, evaluation.runs) + [""]
        lines += improvements(scores, set_name, config.targets) + target_lines(scores, set_name, config.targets)
        lines += [""] + camera_table(evaluation.cameras, set_name) + difference_lines(evaluation.differences, set_name)
        lines += channel_lines(evaluation.channels, set_name)
    focus_row = DEEPSEE if DEEPSEE in set(predictions.row) else predictions.row.iloc[0]
    focus = predictions[(predictions.set == TEST_TRAJECTORIES) & (predictions["round"] == predictions["round"].min())]
    if not focus.empty:
        main = focus[focus.row == focus_row]
        figures = [
            _plot_timeseries(main, config.evaluation.plot_runs, out / TIMESERIES_PNG),
            _plot_scatter(
                focus, [r for r in (focus_row, RANDOM_FOREST, LSTM) if r in set(focus.row)], out / SCATTER_PNG
            ),
            _plot_confusion(
                confusion(
                    advisory_bins(main, main.estimate_m.to_numpy(), main.true_m.to_numpy(), pulses.window_s), pulses
                ),
                out / CONFUSION_PNG,
            ),
        ]
        reliability = evaluation.calibration
        reliability = reliability[
            (reliability.set == TEST_TRAJECTORIES)
            & (reliability.row == focus_row)
            & (reliability["round"] == focus["round"].min())
        ]
        if not reliability.empty:
            figures.append(_plot_reliability(reliability, out / RELIABILITY_PNG))
        lines += [f"## Figures ({focus_row}, test trajectories, round {int(focus['round'].min())})", ""]
        lines += [f"![{p.stem}]({p.name})" for p in figures] + [""]
    path = out / REPORT_MD
    path.write_text("\n".join(lines))
    return path
