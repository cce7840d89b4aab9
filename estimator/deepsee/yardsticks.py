"""Yardsticks of estimate quality that do not reward the base rate, beside the Table 3 figures of
:mod:`estimator.deepsee.metrics`. Pure: arrays in, numbers out.

- **Quadratic-weighted Cohen's κ** of the Equation 2 classes of the 1/3 s bins (the advisory's unit), over every
  class 0 … Equation 2's maximum: 1 when every bin's class is right, 0 for any constant class (its agreement with
  the truth is what chance gives), below 0 when worse than chance. Raw agreement rewards the most frequent class; κ
  does not. The value of scikit-learn's ``cohen_kappa_score(weights="quadratic")`` (the tests hold the two equal),
  from a confusion matrix counted with ``np.bincount``: scikit-learn's checks of its arguments cost 3 ms a call in
  the bootstrap's thousands.
- **Sparsification** (per window): remove windows in order of decreasing estimate and follow the mean *true* error
  of the windows kept; the oracle removes them in order of decreasing truth, a random order keeps the mean where it
  started. Both curves are divided by the mean true error of all windows (so they start at 1) and sampled at the
  removed fractions 0, 1/S, …, (S − 1)/S (S = :data:`SPARSIFICATION_STEPS`). AUSE is the mean gap between the
  estimate's curve and the oracle's (0 for an estimate that orders the windows as their truths do), AURG the mean
  gap between the random curve (1) and the estimate's (0 for a constant, above 0 when the order helps). Windows
  with equal estimates are removed together: each counts at the mean truth of its tie, so a constant estimate's
  curve is exactly flat.
- **AURG to the top class** (``aurg_capped``): the same AURG with every true error from the advisory's top class
  boundary (Equation 2's β, ``large_error_m``) on counted at that boundary. Where a few windows are metres off (a
  SLAM trial tracking across a jump of its map), they hold most of a set's summed error and AURG mostly says which
  row removes them first; the motion statistic finds them by construction, since the jump is in the estimated
  trajectory. For the advisory every error from β on is the same class, so this one says how a row ranks the
  errors the advisory tells apart.
- **Partial Spearman ρ** of the estimate with the truth given the window's motion statistic
  (:func:`estimator.deepsee.references.motion_statistic`): how much of the ranking is not the motion's. The
  first-order partial correlation of scipy's ``spearmanr`` matrix, the value of pingouin's
  ``partial_corr(method="spearman")`` (the tests hold the two equal) without its table building, which cost 7 ms a
  call in the bootstrap's thousands; where that matrix is singular, the defined values (below), not a
  pseudo-inverse's.
- **Head calibration**: per threshold t_k of an ordinal head, the Brier score (scikit-learn's
  ``brier_score_loss``) of P(error ≥ t_k) against 1[truth ≥ t_k] per window, the reliability diagram
  (``calibration_curve``, :data:`RELIABILITY_BINS` equal-width bins of the probability) and its expected calibration
  error, ECE = Σ_b (n_b / n) · |observed_b − mean probability_b|.
- **Confidence intervals by bootstrap over runs**: the windows of one run are not independent (a run's errors
  come in stretches), so the runs are resampled with replacement, all windows and bins of a drawn run together;
  the interval is the percentile interval of the resampled values. The effective n is the number of runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy.stats import spearmanr
from sklearn.calibration import calibration_curve
from sklearn.metrics import brier_score_loss

#: Removed fractions at which a sparsification curve is sampled: 0, 1/S, …, (S − 1)/S.
SPARSIFICATION_STEPS = 100
#: Equal-width probability bins of a reliability diagram.
RELIABILITY_BINS = 10


def quadratic_kappa(true_class: np.ndarray, estimate_class: np.ndarray, classes: int) -> float:
    """Quadratic-weighted κ of two class sequences over the classes 0 … ``classes`` − 1 (pairs with a class outside
    them are left out, as scikit-learn leaves out labels not asked for); NaN when there is nothing to judge or the
    truth and the estimate are one and the same constant (κ is 0 / 0 there)."""
    true_class, estimate_class = np.asarray(true_class, int), np.asarray(estimate_class, int)
    inside = (true_class >= 0) & (true_class < classes) & (estimate_class >= 0) & (estimate_class < classes)
    true_class, estimate_class = true_class[inside], estimate_class[inside]
    if len(true_class) == 0 or (len(set(true_class)) == 1 and set(true_class) == set(estimate_class)):
        return float("nan")
    confusion = np.bincount(true_class * classes + estimate_class, minlength=classes * classes).reshape(classes, -1)
    expected = np.outer(confusion.sum(axis=1), confusion.sum(axis=0)) / len(true_class)
    weights = np.subtract.outer(np.arange(classes), np.arange(classes)) ** 2
    return float(1.0 - np.sum(weights * confusion) / np.sum(weights * expected))


def _kept_means(order_key: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Mean truth of the windows kept after removing the largest ``order_key`` first, at each sampled fraction;
    windows of equal key count at their tie's mean truth."""
    order = np.argsort(order_key, kind="stable")
    key, values = order_key[order], truth[order].astype(float)
    _, start, counts = np.unique(key, return_index=True, return_counts=True)
    tie_means = np.add.reduceat(values, start) / counts
    averaged = np.repeat(tie_means, counts)
    kept = len(values) - np.floor(np.arange(SPARSIFICATION_STEPS) / SPARSIFICATION_STEPS * len(values)).astype(int)
    return np.cumsum(averaged)[kept - 1] / kept


def _relative_kept_means(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray | None:
    """:func:`_kept_means` of ``estimate`` over the mean truth; None without windows or with a zero mean truth."""
    if len(truth) == 0 or not truth.mean() > 0:
        return None
    return _kept_means(estimate, truth) / truth.mean()


def sparsification(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(AUSE, AURG) of ``estimate`` against ``truth`` (module docstring); NaN without windows or with a zero mean
    truth."""
    estimate, truth = np.asarray(estimate, float), np.asarray(truth, float)
    by_estimate = _relative_kept_means(estimate, truth)
    if by_estimate is None:
        return float("nan"), float("nan")
    oracle = _kept_means(truth, truth) / truth.mean()
    return float(np.mean(by_estimate - oracle)), float(np.mean(1.0 - by_estimate))


def capped_aurg(estimate: np.ndarray, truth: np.ndarray, cap_m: float) -> float:
    """AURG of ``estimate`` against ``truth`` with every truth above ``cap_m`` counted as ``cap_m`` (module
    docstring); NaN as :func:`sparsification`. The AURG alone: no oracle curve."""
    by_estimate = _relative_kept_means(np.asarray(estimate, float), np.minimum(np.asarray(truth, float), cap_m))
    return float("nan") if by_estimate is None else float(np.mean(1.0 - by_estimate))


def spearman(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Spearman ρ; NaN for fewer than 3 windows or a constant side."""
    if len(truth) < 3 or np.ptp(estimate) == 0 or np.ptp(truth) == 0:
        return float("nan")
    return float(spearmanr(estimate, truth).statistic)


def partial_spearman(estimate: np.ndarray, truth: np.ndarray, motion: np.ndarray) -> float:
    """Spearman ρ of ``estimate`` with ``truth`` given ``motion``; NaN for fewer than 4 windows, a constant
    variable, a motion statistic that is not finite everywhere, or an estimate or a truth ranked exactly as the
    motion (nothing is left of it once the motion is removed)."""
    if len(truth) < 4 or not np.isfinite(motion).all() or min(np.ptp(estimate), np.ptp(truth), np.ptp(motion)) == 0:
        return float("nan")
    rho = spearmanr(np.column_stack([estimate, truth, motion])).statistic
    with_truth, estimate_motion, truth_motion = rho[0, 1], rho[0, 2], rho[1, 2]
    if max(abs(estimate_motion), abs(truth_motion)) > 1.0 - 1e-12:
        return float("nan")
    if abs(with_truth) > 1.0 - 1e-12:
        # Ranked as the truth (the ceiling's best case): what is left of both after the motion is the same.
        return float(np.sign(with_truth))
    # The first-order partial correlation, which pingouin computes from the inverse of the same matrix.
    return float(
        np.clip(
            (with_truth - estimate_motion * truth_motion)
            / np.sqrt((1.0 - estimate_motion**2) * (1.0 - truth_motion**2)),
            -1.0,
            1.0,
        )
    )


def median_ratio(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Median estimate over median truth; NaN without windows or with a median truth of 0."""
    if len(truth) == 0 or not np.median(truth) > 0:
        return float("nan")
    return float(np.median(estimate) / np.median(truth))


@dataclass(frozen=True)
class Calibration:
    """One head threshold on a set of windows: Brier score, ECE and the reliability diagram's non-empty bins."""

    threshold_m: float
    brier: float
    ece: float
    confidence: np.ndarray  # mean probability per bin
    observed: np.ndarray  # share of windows at or above the threshold per bin
    count: np.ndarray  # windows per bin


def calibration(probability: np.ndarray, truth: np.ndarray, threshold_m: float) -> Calibration:
    """Brier score, ECE and reliability diagram of P(error ≥ ``threshold_m``) against the windows' ``truth``."""
    probability, truth = np.asarray(probability, float), np.asarray(truth, float)
    if len(truth) == 0:
        return Calibration(threshold_m, float("nan"), float("nan"), np.zeros(0), np.zeros(0), np.zeros(0, int))
    outcome = (truth >= threshold_m).astype(int)
    brier = float(brier_score_loss(outcome, probability, pos_label=1))
    # calibration_curve drops empty bins; the counts come from the same bins (its edges and its searchsorted).
    edges = np.linspace(0.0, 1.0, RELIABILITY_BINS + 1)
    count = np.bincount(np.searchsorted(edges[1:-1], probability), minlength=RELIABILITY_BINS)
    count = count[count > 0]
    observed, confidence = calibration_curve(
        outcome, probability, n_bins=RELIABILITY_BINS, strategy="uniform", pos_label=1
    )
    ece = float(np.sum(count / count.sum() * np.abs(observed - confidence)))
    return Calibration(threshold_m, brier, ece, confidence, observed, count)


@dataclass(frozen=True)
class Judged:
    """One estimator's windows of one set and their advisory bins, as the yardsticks read them. Window arrays are
    (N,), bin arrays (B,); ``*_run`` says which run each belongs to (the unit of the bootstrap)."""

    window_run: np.ndarray
    truth_m: np.ndarray
    estimate_m: np.ndarray
    motion: np.ndarray
    bin_run: np.ndarray
    bin_truth_m: np.ndarray
    bin_estimate_m: np.ndarray
    bin_true_class: np.ndarray
    bin_estimate_class: np.ndarray

    def take(self, windows: np.ndarray, bins: np.ndarray) -> Judged:
        """The windows ``windows`` and the bins ``bins`` (indices, repeats allowed)."""
        return Judged(
            self.window_run[windows],
            self.truth_m[windows],
            self.estimate_m[windows],
            self.motion[windows],
            self.bin_run[bins],
            self.bin_truth_m[bins],
            self.bin_estimate_m[bins],
            self.bin_true_class[bins],
            self.bin_estimate_class[bins],
        )


#: The yardsticks of :func:`yardsticks` that get a bootstrap interval (``<name>_low``, ``<name>_high``).
WITH_INTERVALS = (
    "agreement",
    "kappa",
    "aurg",
    "aurg_capped",
    "spearman",
    "partial_spearman",
    "median_ratio",
    "recall_large",
)


def yardsticks(judged: Judged, classes: int, large_error_m: float) -> dict[str, float]:
    """Agreement, κ and recall of ≥ ``large_error_m`` bins (bins); Spearman ρ, partial ρ given motion, AUSE,
    AURG, AURG with the truth capped at ``large_error_m`` and median ratio (windows)."""
    large = judged.bin_truth_m >= large_error_m
    ause, aurg = sparsification(judged.estimate_m, judged.truth_m)
    return {
        "agreement": float(np.mean(judged.bin_true_class == judged.bin_estimate_class))
        if len(judged.bin_run)
        else float("nan"),
        "kappa": quadratic_kappa(judged.bin_true_class, judged.bin_estimate_class, classes),
        "recall_large": float(np.mean(judged.bin_estimate_m[large] >= large_error_m)) if large.any() else float("nan"),
        "spearman": spearman(judged.estimate_m, judged.truth_m),
        "partial_spearman": partial_spearman(judged.estimate_m, judged.truth_m, judged.motion),
        "ause": ause,
        "aurg": aurg,
        "aurg_capped": capped_aurg(judged.estimate_m, judged.truth_m, large_error_m),
        "median_ratio": median_ratio(judged.estimate_m, judged.truth_m),
    }


@dataclass(frozen=True)
class Bootstrap:
    """Percentile intervals by resampling runs: ``resamples`` draws, ``confidence`` (e.g. 0.95), seeded."""

    resamples: int
    confidence: float
    seed: int


def _run_draws(judged: Judged, settings: Bootstrap) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The windows and bins (indices, repeats allowed) of ``settings.resamples`` sets of runs drawn with
    replacement, seeded; nothing with fewer than 2 runs."""
    runs, window_run = np.unique(judged.window_run, return_inverse=True)
    if len(runs) < 2:
        return
    bin_run = np.searchsorted(runs, judged.bin_run)
    windows_of = [np.flatnonzero(window_run == k) for k in range(len(runs))]
    bins_of = [np.flatnonzero(bin_run == k) for k in range(len(runs))]
    rng = np.random.default_rng(settings.seed)
    for _ in range(settings.resamples):
        draw = rng.integers(len(runs), size=len(runs))
        yield np.concatenate([windows_of[k] for k in draw]), np.concatenate([bins_of[k] for k in draw])


def bootstrap_over_runs(
    judged: Judged, statistic: Callable[[Judged], dict[str, float]], names: tuple[str, ...], settings: Bootstrap
) -> tuple[dict[str, tuple[float, float]], int]:
    """Percentile intervals of ``statistic``'s ``names`` over sets of runs drawn with replacement, and the
    effective n (the number of runs). With fewer than 2 runs (or no resamples) every interval is NaN."""
    values: dict[str, list[float]] = {name: [] for name in names}
    for windows, bins in _run_draws(judged, settings):
        result = statistic(judged.take(windows, bins))
        for name in names:
            values[name].append(result[name])
    runs = len(np.unique(judged.window_run))
    return {name: _percentile_interval(values[name], settings.confidence) for name in names}, runs


def paired_differences(
    judged_a: Judged,
    judged_b: Judged,
    statistic: Callable[[Judged], dict[str, float]],
    names: tuple[str, ...],
    settings: Bootstrap,
) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """``statistic``'s ``names`` of estimator a minus those of estimator b on the same windows and bins (the two
    :class:`Judged` differ only in their estimates), and the percentile interval of each difference over sets of
    runs drawn with replacement, the same draw for both: the interval of a paired comparison, which two intervals
    side by side are not. NaN intervals with fewer than 2 runs."""
    point_a, point_b = statistic(judged_a), statistic(judged_b)
    values: dict[str, list[float]] = {name: [] for name in names}
    for windows, bins in _run_draws(judged_a, settings):
        a, b = statistic(judged_a.take(windows, bins)), statistic(judged_b.take(windows, bins))
        for name in names:
            values[name].append(a[name] - b[name])
    points = {name: point_a[name] - point_b[name] for name in names}
    return points, {name: _percentile_interval(values[name], settings.confidence) for name in names}


def _percentile_interval(values: list[float], confidence: float) -> tuple[float, float]:
    """The percentile interval of the finite ``values``; NaN without one."""
    finite = np.asarray(values, float)
    finite = finite[np.isfinite(finite)]
    if not len(finite):
        return float("nan"), float("nan")
    tail = 100.0 * (1.0 - confidence) / 2.0
    return float(np.percentile(finite, tail)), float(np.percentile(finite, 100.0 - tail))
