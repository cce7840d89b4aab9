"""Reference rows: what an estimate must beat, judged on exactly the windows and bins the models are judged on.

- ``constant``: the Equation 2 class most frequent among the training data's 1/3 s bins, estimated everywhere as
  the median of those bins' mean errors (a value inside that class). Its agreement is the base rate; its κ is 0.
- ``always_top``: every window at the top class boundary (12 mm with the paper's values): "always 3 pulses".
- ``motion_isotonic``: the motion alone. The window's motion statistic (:func:`motion_statistic`: the standard
  deviation over the window of the camera's displacement per frame, sqrt(var(rel_tx) + var(rel_ty) +
  var(rel_tz)), in m/frame) mapped to an error by scikit-learn's ``IsotonicRegression`` (its direction chosen by the
  sign of the training data's Spearman ρ, estimates clipped to the training range) fitted on the training windows.
  The statistic is fixed here, not chosen on any data.
- ``ceiling``: for a run of the dataset whose rendered sequence was tracked more than once (``trials`` of the
  build), the estimate of a window is the true error of the other trials at the same frame (their mean where there
  are several): how well one SLAM trial's error predicts another's. Windows whose frame no other trial labelled have
  no ceiling estimate and are left out of the ceiling's row (its window count says how many remain). For
  out-of-domain session folders, the trials are the other sessions of the same source and mode
  (:func:`session_ceiling_estimates`).

Everything is fitted on the training part of the round (or, for fine-tuning, on the sessions it trains on); test
data and the lockbox are only judged.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.isotonic import IsotonicRegression

from estimator.dataset.store import WITH_SAMPLES, DatasetReader, list_runs
from estimator.deepsee.data import Windows, session_frame_labels, session_mode
from estimator.deepsee.metrics import advisory_bins, pulse_classes
from estimator.deepsee.yardsticks import spearman
from seesys.core import rts_schema
from seesys.core.equation2 import PulseSettings
from seesys.core.errors import SeesysError
from seesys.core.exceedance import class_boundaries_m
from seesys.core.labels import LabelStatus
from seesys.core.motion import translation_spread
from seesys.io import session_files

CONSTANT = "constant"
ALWAYS_TOP = "always_top"
MOTION_ISOTONIC = "motion_isotonic"
CEILING = "ceiling"


@dataclass(frozen=True)
class ReferenceRow:
    name: str  # the row's name in scores.csv
    label: str  # as in the report
    category: str


REFERENCE_ROWS = (
    ReferenceRow(CONSTANT, "constant (training's most frequent class)", "Reference"),
    ReferenceRow(ALWAYS_TOP, "always the top class", "Reference"),
    ReferenceRow(MOTION_ISOTONIC, "motion only (isotonic)", "Reference"),
)
CEILING_ROW = ReferenceRow(CEILING, "another SLAM trial of the same render", "Ceiling")


def motion_statistic(rts: np.ndarray) -> np.ndarray:
    """(N, T, C) windows normalised by :func:`seesys.core.rts_schema.normalise` (every channel of the schema) → (N,)
    standard deviation over the window of the relative translation, sqrt(Σ var(rel_t·)), in m/frame."""
    rts = np.asarray(rts, np.float64)
    if rts.ndim != 3 or rts.shape[-1] != rts_schema.NUM_CHANNELS:
        raise SeesysError(
            f"the motion statistic takes windows of every RTS channel ({rts_schema.NUM_CHANNELS}), "
            f"got shape {rts.shape}"
        )
    columns = [rts_schema.index_of(name) for name in rts_schema.TRANSLATION_CHANNELS]
    scales = np.array([rts_schema.CHANNELS[c].scale for c in columns])
    return translation_spread(rts[..., columns] * scales)


@dataclass(frozen=True)
class References:
    """The reference estimators fitted on one training set."""

    constant_m: float
    constant_class: int
    top_m: float
    motion_fit: IsotonicRegression

    def estimates(self, windows: Windows) -> dict[str, np.ndarray]:
        """Each reference row's estimates (metres) of ``windows``."""
        n = len(windows)
        return {
            CONSTANT: np.full(n, self.constant_m),
            ALWAYS_TOP: np.full(n, self.top_m),
            MOTION_ISOTONIC: self.motion_fit.predict(motion_statistic(windows.rts)) if n else np.zeros(0),
        }


def fit_references(train: Windows, pulses: PulseSettings) -> References:
    """The references of :data:`REFERENCE_ROWS`, fitted on ``train`` (module docstring); raises
    :class:`SeesysError` without training windows."""
    if not len(train):
        raise SeesysError("no training windows to fit the reference rows on")
    bins = advisory_bins(train.meta, train.error_m, train.error_m, pulses.window_s)
    classes = pulse_classes(bins.truth.to_numpy(), pulses)
    counts = np.bincount(classes, minlength=pulses.max_pulses + 1)
    best = int(np.argmax(counts))
    motion = motion_statistic(train.rts)
    increasing = not spearman(motion, train.error_m) < 0
    fit = IsotonicRegression(increasing=increasing, out_of_bounds="clip").fit(motion, train.error_m)
    return References(
        float(np.median(bins.truth.to_numpy()[classes == best])), best, class_boundaries_m(pulses)[-1], fit
    )


def other_trials(roots: list[Path]) -> dict[str, list[str]]:
    """For every run with samples of the dataset folders, the runs of the same rendered sequence and mode with
    another trial (empty where it was tracked once)."""
    infos = [info for root in roots for info in list_runs(root) if info.status in WITH_SAMPLES]
    by_sequence: dict[tuple[str, str], list[str]] = {}
    for info in infos:
        by_sequence.setdefault((info.sequence, info.mode), []).append(info.run)
    return {info.run: [r for r in by_sequence[(info.sequence, info.mode)] if r != info.run] for info in infos}


def mean_of_other_trials(
    meta: pd.DataFrame, others: dict[str, list[str]], labels_of: Callable[[list[str]], pd.Series]
) -> np.ndarray:
    """Per window (``meta``'s rows: ``run``, ``frame_index``, a positional index), the mean true error of the other
    trials ``others[run]`` at its end frame; NaN where no other trial labelled that frame. ``labels_of(runs)``: the
    labelled frames' true errors of those runs, indexed by run and frame index (asked once, for the trials needed).
    The ceiling's estimate, wherever its trials and their labels come from."""
    estimate = np.full(len(meta), np.nan)
    wanted = sorted({o for run in set(meta.run) for o in others.get(run, [])})
    if not wanted:
        return estimate
    labels = labels_of(wanted)
    labelled_runs = set(labels.index.get_level_values(0))
    for run, rows in meta.groupby("run", sort=False).groups.items():
        per_trial = [
            labels.loc[o].reindex(meta.frame_index.to_numpy()[np.asarray(rows)]).to_numpy()
            for o in others.get(run, [])
            if o in labelled_runs
        ]
        if per_trial:
            stacked = np.vstack(per_trial)
            finite = np.isfinite(stacked).any(axis=0)
            estimate[np.asarray(rows)[finite]] = np.nanmean(stacked[:, finite], axis=0)
    return estimate


def ceiling_estimates(roots: list[Path], windows: Windows) -> np.ndarray:
    """Per window of dataset runs, the mean true error of the other trials of its run's sequence at its end frame;
    NaN where there is no other trial or none labelled that frame (module docstring)."""

    def labels_of(runs: list[str]) -> pd.Series:
        labels = DatasetReader(roots, runs=runs).frame_labels()
        return labels[labels.status == LabelStatus.LABELLED.value].set_index(["run", "frame_index"]).error_m

    return mean_of_other_trials(windows.meta, other_trials(roots) if len(windows) else {}, labels_of)


def other_session_trials(sessions: list[Path]) -> dict[str, list[str]]:
    """For every session folder (by its folder's name), the other folders that tracked the same source in the same
    mode (their ``session.json``'s ``source`` and ``mode``, as written): SLAM trials of one recording. A session
    whose ``session.json`` names no source has none."""
    recorded: dict[str, tuple[str, str] | None] = {}
    for folder in map(Path, sessions):
        source = session_files.read_manifest(folder).get("source")
        recorded[folder.name] = (str(source), session_mode(folder)) if source else None
    return {
        name: [o for o, key in recorded.items() if o != name and key is not None and key == recorded[name]]
        for name in recorded
    }


def session_ceiling_estimates(sessions: list[Path], windows: Windows) -> np.ndarray:
    """Per window of labelled session folders (``windows.meta.run``: the folder's name), the mean true error of the
    other sessions of the same source and mode (:func:`other_session_trials`) at its end frame, labelled as
    :func:`estimator.deepsee.data.session_windows` labels them; NaN where there is no such session or none labelled
    that frame. The ceiling of out-of-domain sessions: track one recording several times to have it."""
    folders = {Path(s).name: Path(s) for s in sessions}

    def labels_of(runs: list[str]) -> pd.Series:
        labels = pd.concat({run: session_frame_labels(folders[run]) for run in runs}, names=["run", "frame_index"])
        return labels[labels.status == LabelStatus.LABELLED.value].error_m

    return mean_of_other_trials(windows.meta, other_session_trials(sessions) if len(windows) else {}, labels_of)
