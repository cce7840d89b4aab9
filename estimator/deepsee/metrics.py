"""How estimates are judged: the paper's RMSE and MAPE, the same RMSE on the paper's label range, the rank
correlation, and what the audio advisory would do with the estimates.

Advisory figures: the windows of each run are grouped into consecutive 1/3 s bins (the advisory's moving-average
window, ``[timing] window_s`` of configs/advisory.toml) by their end time; the estimates and the true errors of a
bin are averaged, and each mean is turned into Equation 2's pulse count (0–3) with the advisory's own rule
(:meth:`seesys.core.equation2.PulseSettings.pulses`). ``agreement`` is the share of bins where both counts are equal;
``recall_large`` the share of bins whose true mean is at least ``large_error_m`` (12 mm: the top class) that the
estimates also put there.

Where a model's ordinal head gives P(error ≥ t_k) for exactly Equation 2's class boundaries, the head is judged as
the advisory uses it: its probabilities are averaged over the same bins and the bin's class is the number of means
at least 0.5 (:func:`seesys.core.exceedance.head_class`). ``head_agreement`` is the share of bins where that class
equals the true mean's Equation 2 class; ``head_recall_large`` the share of bins with a true mean ≥ ``large_error_m``
whose head class is at least that error's class. Both are NaN for a model without a head.

Beside these, the yardsticks of :mod:`estimator.deepsee.yardsticks` that do not reward the base rate: κ of the
bins' classes (and of the head's), AUSE and AURG, the partial Spearman ρ given the window's motion statistic, the
head's Brier score and ECE (means over its thresholds), each with a bootstrap interval over runs where listed in
:data:`~estimator.deepsee.yardsticks.WITH_INTERVALS`, and the effective n (``runs``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimator.deepsee.config import EvaluationConfig
from estimator.deepsee.yardsticks import (
    WITH_INTERVALS,
    Bootstrap,
    Judged,
    bootstrap_over_runs,
    calibration,
    quadratic_kappa,
    yardsticks,
)
from seesys.core.equation2 import PulseSettings
from seesys.core.exceedance import class_boundaries_m, head_class, same_thresholds

CM_PER_M = 100.0


@dataclass(frozen=True)
class Scores:
    windows: int
    rmse_cm: float
    rmse_paper_range_cm: float
    mape: float
    spearman: float
    agreement: float
    recall_large: float
    bins: int
    large_bins: int
    head_agreement: float = float("nan")
    head_recall_large: float = float("nan")
    # median estimate / median true error: how far a model's level is off on a camera or scene it did not see
    median_ratio: float = float("nan")
    # The yardsticks that do not reward the base rate (estimator/deepsee/yardsticks.py).
    kappa: float = float("nan")
    ause: float = float("nan")
    aurg: float = float("nan")
    aurg_capped: float = float("nan")  # the truth capped at the top class boundary (large_error_m)
    partial_spearman: float = float("nan")  # given the window's motion statistic
    head_kappa: float = float("nan")
    head_brier: float = float("nan")  # mean over the head's thresholds
    head_ece: float = float("nan")
    runs: int = 0  # the effective n of the intervals: runs (sessions) resampled
    agreement_low: float = float("nan")
    agreement_high: float = float("nan")
    kappa_low: float = float("nan")
    kappa_high: float = float("nan")
    aurg_low: float = float("nan")
    aurg_high: float = float("nan")
    aurg_capped_low: float = float("nan")
    aurg_capped_high: float = float("nan")
    spearman_low: float = float("nan")
    spearman_high: float = float("nan")
    partial_spearman_low: float = float("nan")
    partial_spearman_high: float = float("nan")
    median_ratio_low: float = float("nan")
    median_ratio_high: float = float("nan")
    recall_large_low: float = float("nan")
    recall_large_high: float = float("nan")


def equation2_head(
    probabilities: np.ndarray | None, thresholds_m: Sequence[float], pulses: PulseSettings
) -> np.ndarray | None:
    """``probabilities`` when their ``thresholds_m`` are Equation 2's class boundaries (the head's class is then
    Equation 2's), else None: a head of other thresholds is not judged against Equation 2's classes."""
    if probabilities is None or not same_thresholds(thresholds_m, class_boundaries_m(pulses)):
        return None
    return probabilities


def bin_index(meta: pd.DataFrame, window_s: float) -> np.ndarray:
    """The advisory bin of each window: ``window_s`` long, counted from its run's first window."""
    t = pd.Series(meta.timestamp.to_numpy(float))
    return np.floor((t - t.groupby(meta.run.to_numpy()).transform("min")) / window_s).astype(int).to_numpy()


def advisory_bins(meta: pd.DataFrame, estimate_m: np.ndarray, true_m: np.ndarray, window_s: float) -> pd.DataFrame:
    """Mean estimate and mean truth per run and 1/3 s bin (:func:`bin_index`)."""
    table = pd.DataFrame(
        {"run": meta.run.to_numpy(), "estimate": estimate_m, "truth": true_m, "bin": bin_index(meta, window_s)}
    )
    return table.groupby(["run", "bin"], sort=False)[["estimate", "truth"]].mean().reset_index()


def pulse_classes(errors_m: np.ndarray, pulses: PulseSettings) -> np.ndarray:
    return np.array([pulses.pulses(float(e)) for e in errors_m], int)


def confusion(bins: pd.DataFrame, pulses: PulseSettings) -> np.ndarray:
    """(true class, estimated class) counts, classes 0 … Equation 2's maximum."""
    n = pulses.max_pulses + 1
    matrix = np.zeros((n, n), int)
    np.add.at(
        matrix, (pulse_classes(bins.truth.to_numpy(), pulses), pulse_classes(bins.estimate.to_numpy(), pulses)), 1
    )
    return matrix


def _head_scores(
    meta: pd.DataFrame,
    probabilities: np.ndarray,
    bins: pd.DataFrame,
    evaluation: EvaluationConfig,
    pulses: PulseSettings,
) -> tuple[float, float, float]:
    """(head agreement, head recall of large-error bins, head κ) over the bins of :func:`advisory_bins`."""
    columns = [f"p{k}" for k in range(probabilities.shape[1])]
    table = pd.DataFrame(probabilities, columns=columns)
    table["run"] = meta.run.to_numpy()
    table["bin"] = bin_index(meta, pulses.window_s)
    means = (
        table.groupby(["run", "bin"], sort=False)[columns]
        .mean()
        .reset_index()
        .merge(bins[["run", "bin", "truth"]], on=["run", "bin"], validate="one_to_one")
    )
    classes = head_class(means[columns].to_numpy())
    truth = pulse_classes(means.truth.to_numpy(), pulses)
    large = (means.truth >= evaluation.large_error_m).to_numpy()
    recall = float((classes[large] >= pulses.pulses(evaluation.large_error_m)).mean()) if large.any() else np.nan
    return (float(np.mean(classes == truth)), recall, quadratic_kappa(truth, classes, pulses.max_pulses + 1))


def bootstrap_settings(evaluation: EvaluationConfig) -> Bootstrap:
    return Bootstrap(evaluation.bootstrap_resamples, evaluation.confidence, evaluation.bootstrap_seed)


def _head_calibration(probabilities: np.ndarray, true_m: np.ndarray, pulses: PulseSettings) -> tuple[float, float]:
    """(mean Brier score, mean ECE) over the head's thresholds, Equation 2's class boundaries."""
    each = [calibration(probabilities[:, k], true_m, t) for k, t in enumerate(class_boundaries_m(pulses))]
    return float(np.mean([c.brier for c in each])), float(np.mean([c.ece for c in each]))


def judged(
    meta: pd.DataFrame, estimate_m: np.ndarray, true_m: np.ndarray, motion: np.ndarray, pulses: PulseSettings
) -> Judged:
    """The windows and their advisory bins (:func:`advisory_bins`) as :mod:`estimator.deepsee.yardsticks` reads
    them."""
    bins = advisory_bins(meta, estimate_m, true_m, pulses.window_s)
    return Judged(
        meta.run.to_numpy().astype(str),
        true_m,
        estimate_m,
        np.asarray(motion, float),
        bins.run.to_numpy().astype(str),
        bins.truth.to_numpy(),
        bins.estimate.to_numpy(),
        pulse_classes(bins.truth.to_numpy(), pulses),
        pulse_classes(bins.estimate.to_numpy(), pulses),
    )


def score(
    meta: pd.DataFrame,
    estimate_m: np.ndarray,
    true_m: np.ndarray,
    evaluation: EvaluationConfig,
    pulses: PulseSettings,
    probabilities: np.ndarray | None = None,
    motion: np.ndarray | None = None,
) -> Scores:
    """The scores of one model on windows ``meta``; ``probabilities``: its head's P(error ≥ t_k) (N, K) for
    Equation 2's class boundaries (:func:`equation2_head`), None to leave the head's scores NaN; ``motion``: each
    window's motion statistic (:func:`estimator.deepsee.references.motion_statistic`), None to leave the partial ρ
    NaN."""
    estimate_m, true_m = np.asarray(estimate_m, float), np.asarray(true_m, float)
    if len(true_m) == 0:
        nan = float("nan")
        return Scores(0, nan, nan, nan, nan, nan, nan, 0, 0)
    error = estimate_m - true_m
    low, high = evaluation.paper_range_m
    in_range = (true_m >= low) & (true_m <= high)
    positive = true_m > 0
    bins = advisory_bins(meta, estimate_m, true_m, pulses.window_s)
    matrix = confusion(bins, pulses)
    large = bins.truth >= evaluation.large_error_m
    head = (
        _head_scores(meta, probabilities, bins, evaluation, pulses)
        if probabilities is not None
        else (np.nan, np.nan, np.nan)
    )
    calibrated = _head_calibration(probabilities, true_m, pulses) if probabilities is not None else (np.nan, np.nan)
    windows = judged(meta, estimate_m, true_m, np.full(len(true_m), np.nan) if motion is None else motion, pulses)
    classes = pulses.max_pulses + 1

    def statistic(j: Judged) -> dict[str, float]:
        return yardsticks(j, classes, evaluation.large_error_m)

    point = statistic(windows)
    intervals, runs = bootstrap_over_runs(windows, statistic, WITH_INTERVALS, bootstrap_settings(evaluation))
    return Scores(
        windows=len(true_m),
        rmse_cm=CM_PER_M * float(np.sqrt(np.mean(error**2))),
        rmse_paper_range_cm=CM_PER_M * float(np.sqrt(np.mean(error[in_range] ** 2))) if in_range.any() else np.nan,
        mape=float(np.mean(np.abs(error[positive]) / true_m[positive])) if positive.any() else np.nan,
        spearman=point["spearman"],
        agreement=float(np.trace(matrix) / matrix.sum()),
        recall_large=float((bins.estimate[large] >= evaluation.large_error_m).mean()) if large.any() else np.nan,
        bins=len(bins),
        large_bins=int(large.sum()),
        head_agreement=head[0],
        head_recall_large=head[1],
        median_ratio=point["median_ratio"],
        kappa=point["kappa"],
        ause=point["ause"],
        aurg=point["aurg"],
        aurg_capped=point["aurg_capped"],
        partial_spearman=point["partial_spearman"],
        head_kappa=head[2],
        head_brier=calibrated[0],
        head_ece=calibrated[1],
        runs=runs,
        **{
            f"{name}_{side}": value
            for name, (low_value, high_value) in intervals.items()
            for side, value in (("low", low_value), ("high", high_value))
        },
    )
