"""How estimates are judged: the paper's RMSE and MAPE, the same RMSE on the paper's label range, the rank
correlation, and what the audio advisory would do with the estimates.

Advisory figures: the windows of each run are grouped into consecutive 1/3 s bins (the advisory's moving-average
window, ``[timing] window_s`` of configs/advisory.toml) by their end time; the estimates and the true errors of a
bin are averaged, and each mean is turned into Equation 2's pulse count (0–3) with the advisory's own rule
(:meth:`seesys.core.equation2.PulseSettings.pulses`). ``agreement`` is the share of bins where both counts are equal;
``recall_large`` the share of bins whose true mean is at least ``large_error_m`` (12 mm: the top class) that the
estimates also put there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from estimator.deepsee.config import EvaluationConfig
from seesys.core.equation2 import PulseSettings

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


def advisory_bins(meta: pd.DataFrame, estimate_m: np.ndarray, true_m: np.ndarray, window_s: float) -> pd.DataFrame:
    """Mean estimate and mean truth per run and 1/3 s bin (bins counted from each run's first window)."""
    table = pd.DataFrame({"run": meta.run.to_numpy(), "t": meta.timestamp.to_numpy(float), "estimate": estimate_m,
                          "truth": true_m})
    table["bin"] = np.floor((table.t - table.groupby("run").t.transform("min")) / window_s).astype(int)
    return table.groupby(["run", "bin"], sort=False)[["estimate", "truth"]].mean().reset_index()


def pulse_classes(errors_m: np.ndarray, pulses: PulseSettings) -> np.ndarray:
    return np.array([pulses.pulses(float(e)) for e in errors_m], int)


def confusion(bins: pd.DataFrame, pulses: PulseSettings) -> np.ndarray:
    """(true class, estimated class) counts, classes 0 … Equation 2's maximum."""
    n = pulses.max_pulses + 1
    matrix = np.zeros((n, n), int)
    np.add.at(matrix, (pulse_classes(bins.truth.to_numpy(), pulses),
                       pulse_classes(bins.estimate.to_numpy(), pulses)), 1)
    return matrix


def score(meta: pd.DataFrame, estimate_m: np.ndarray, true_m: np.ndarray, evaluation: EvaluationConfig,
          pulses: PulseSettings) -> Scores:
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
    return Scores(
        windows=len(true_m),
        rmse_cm=CM_PER_M * float(np.sqrt(np.mean(error ** 2))),
        rmse_paper_range_cm=CM_PER_M * float(np.sqrt(np.mean(error[in_range] ** 2))) if in_range.any() else np.nan,
        mape=float(np.mean(np.abs(error[positive]) / true_m[positive])) if positive.any() else np.nan,
        spearman=float(spearmanr(estimate_m, true_m).statistic) if len(true_m) > 2 else np.nan,
        agreement=float(np.trace(matrix) / matrix.sum()),
        recall_large=float((bins.estimate[large] >= evaluation.large_error_m).mean()) if large.any() else np.nan,
        bins=len(bins), large_bins=int(large.sum()))
