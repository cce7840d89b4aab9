"""The RTS channels alone against the label, per evaluation set: how much of the error's ranking a channel holds
that the camera's motion does not. Pure: arrays in, tables out.

For each channel of :data:`seesys.core.rts_schema.GEOMETRY_CATEGORIES` (the pose observability, the residuals and
the second opinion) and each window feature of :data:`estimator.dataset.report.WINDOW_STATISTICS` (the channel's
mean, minimum, maximum and standard deviation over the window and its value at the window's end), on the raw RTS
windows of a set: its Spearman ρ with the label and its partial Spearman ρ given the window's motion statistic
(:func:`estimator.dataset.report.window_motion`), on the windows where the feature, the label and the motion are
known. Each channel's feature is **chosen on the round's training windows** (the largest |partial ρ| there) and
only that one gets an interval on the test sets (bootstrap over runs, :func:`estimator.deepsee.yardsticks.
bootstrap_over_runs`), so that the reported figure is not the best of five looked for on the test data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimator.dataset.report import WINDOW_STATISTICS, window_features, window_motion
from estimator.deepsee.yardsticks import Bootstrap, Judged, bootstrap_over_runs, partial_spearman, spearman
from seesys.core import rts_schema

CORRELATIONS = ("spearman", "partial_spearman")
#: Fewer windows than this with a value: the feature is not judged on that set.
MIN_WINDOWS = 30


def judged_channels() -> tuple[str, ...]:
    """The channels judged alone: those of the schema's geometry categories, in schema order."""
    return tuple(name for category in rts_schema.GEOMETRY_CATEGORIES for name in rts_schema.channel_names(category))


@dataclass(frozen=True)
class RawSet:
    """One set's windows as the channel table reads them: raw RTS (N, T, C) of every schema channel, the label
    (N,) and each window's run (N,)."""

    rts: np.ndarray
    error_m: np.ndarray
    run: np.ndarray

    def subset(self, index: np.ndarray) -> RawSet:
        return RawSet(self.rts[index], self.error_m[index], self.run[index])


def _known(x: np.ndarray, error: np.ndarray, motion: np.ndarray) -> np.ndarray:
    return np.isfinite(x) & np.isfinite(error) & np.isfinite(motion)


def _features(data: RawSet) -> tuple[pd.DataFrame, np.ndarray]:
    """The judged channels' window features and the motion statistic of ``data``."""
    columns = [rts_schema.index_of(name) for name in judged_channels()]
    features = window_features(data.rts, columns)
    return features, window_motion(data.rts)


def choose_features(train: RawSet) -> dict[str, str]:
    """Per judged channel, its window feature (``<channel>_<statistic>``) with the largest |partial ρ| given motion
    on ``train``; a channel without a judged feature there is left out."""
    features, motion = _features(train)
    chosen = {}
    for channel in judged_channels():
        best, best_value = None, -1.0
        for statistic in WINDOW_STATISTICS:
            name = f"{channel}_{statistic}"
            x = features[name].to_numpy(float)
            keep = _known(x, train.error_m, motion)
            if keep.sum() < MIN_WINDOWS:
                continue
            value = abs(partial_spearman(x[keep], train.error_m[keep], motion[keep]))
            if np.isfinite(value) and value > best_value:
                best, best_value = name, value
        if best is not None:
            chosen[channel] = best
    return chosen


def channel_table(data: RawSet, chosen: dict[str, str], bootstrap: Bootstrap) -> pd.DataFrame:
    """One row per judged channel and window feature of ``data``: windows, runs, ρ and partial ρ given motion;
    ``chosen`` (:func:`choose_features`) marks the feature chosen on the training windows, which alone gets the
    bootstrap interval over runs (``<correlation>_low``, ``<correlation>_high``)."""
    features, motion = _features(data)
    rows = []
    for channel in judged_channels():
        for statistic in WINDOW_STATISTICS:
            name = f"{channel}_{statistic}"
            x = features[name].to_numpy(float)
            keep = _known(x, data.error_m, motion)
            row: dict[str, object] = {
                "channel": channel,
                "feature": statistic,
                "chosen": chosen.get(channel) == name,
                "windows": int(keep.sum()),
                "runs": len(set(data.run[keep])),
            }
            point = {c: float("nan") for c in CORRELATIONS}
            intervals = {c: (float("nan"), float("nan")) for c in CORRELATIONS}
            if keep.sum() >= MIN_WINDOWS:
                windows = _as_judged(data.run[keep], data.error_m[keep], x[keep], motion[keep])
                point = _correlations(windows)
                if row["chosen"]:
                    intervals, _ = bootstrap_over_runs(windows, _correlations, CORRELATIONS, bootstrap)
            for c in CORRELATIONS:
                row[c] = point[c]
                row[f"{c}_low"], row[f"{c}_high"] = intervals[c]
            rows.append(row)
    return pd.DataFrame(rows)


def _as_judged(run: np.ndarray, error: np.ndarray, x: np.ndarray, motion: np.ndarray) -> Judged:
    """Windows as the yardsticks' bootstrap reads them, the feature in the estimate's place; no advisory bins."""
    none = np.zeros(0)
    return Judged(run.astype(str), error, x, motion, none.astype(str), none, none, none.astype(int), none.astype(int))


def _correlations(windows: Judged) -> dict[str, float]:
    return {
        "spearman": spearman(windows.estimate_m, windows.truth_m),
        "partial_spearman": partial_spearman(windows.estimate_m, windows.truth_m, windows.motion),
    }
