"""Estimate logs (CSV with columns ``timestamp,error_m`` and optionally ``frame_index``), the input of ``render``
and ``replay``; a log of a model with an ordinal head (``seesys estimator estimate``) also has one column
``p_ge_<threshold in metres>`` per threshold (:func:`seesys.core.exceedance.probability_column`), read as the
estimates' head."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core.errors import SeesysError
from seesys.core.exceedance import column_threshold

COLUMNS = ("timestamp", "error_m")
FRAME_INDEX = "frame_index"


@dataclass(frozen=True)
class EstimateLog:
    timestamps: np.ndarray  # seconds, non-decreasing
    errors_m: np.ndarray
    frame_indices: np.ndarray | None = None  # the logged frame index of each estimate (None: the log has none)
    head_thresholds_m: tuple[float, ...] = ()  # the head's thresholds, increasing (empty: the log has no head)
    head_probabilities: np.ndarray | None = None  # (N, K) P(error ≥ threshold) per estimate; None without a head

    def head(self, row: int) -> tuple[float, ...] | None:
        """Row ``row``'s head probabilities, None for a log without a head."""
        return None if self.head_probabilities is None else tuple(float(p) for p in self.head_probabilities[row])

    def frame_index(self, row: int) -> int:
        """The frame index of row ``row``: the logged one, or the row number in a log without frame indices."""
        return int(self.frame_indices[row]) if self.frame_indices is not None else row


def _collapsed(path: Path, timestamps: np.ndarray) -> str | None:
    """Why the timestamps cannot be a session's times (most rows share a time with the row before), or None.

    A log whose timestamps lost their digits (epoch times written with 9 significant digits keep only 10 s steps)
    would put all its estimates at a few instants: the pulses pile up there instead of following the session."""
    repeats = int(np.count_nonzero(np.diff(timestamps) == 0))
    if repeats * 2 <= timestamps.size:
        return None
    distinct = np.unique(timestamps).size
    return (
        f"{path}: {timestamps.size} estimates at only {distinct} distinct time(s): its timestamps have lost "
        f"their precision (write them in full, e.g. again with `seesys estimator estimate`)"
    )


def read_estimate_log(path: Path) -> EstimateLog:
    """Read and validate an estimate log; a problem raises a SeesysError naming the file and the row, and so do
    timestamps that collapsed onto a few values."""
    try:
        table = pd.read_csv(path)
    except FileNotFoundError:
        raise SeesysError(f"estimate log not found: {path}") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise SeesysError(f"{path}: not a readable CSV file ({e})") from None
    missing = [c for c in COLUMNS if c not in table.columns]
    if missing:
        raise SeesysError(f"{path}: missing column(s) {', '.join(missing)} (expected {','.join(COLUMNS)})")
    if table.empty:
        raise SeesysError(f"{path}: no estimates")
    values = {}
    for column in COLUMNS:
        numbers = pd.to_numeric(table[column], errors="coerce").to_numpy(dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(numbers) | (numbers < 0 if column == "error_m" else False))
        if bad.size:
            row = int(bad[0])
            raise SeesysError(
                f"{path}: row {row + 2}: {column} {table[column].iloc[row]!r} is not a valid "
                f"{'non-negative number of metres' if column == 'error_m' else 'time in seconds'}"
            )
        values[column] = numbers
    backwards = np.flatnonzero(np.diff(values["timestamp"]) < 0)
    if backwards.size:
        raise SeesysError(f"{path}: row {int(backwards[0]) + 3}: timestamps go backwards")
    collapsed = _collapsed(path, values["timestamp"])
    if collapsed:
        raise SeesysError(collapsed)
    frames = None
    if FRAME_INDEX in table.columns:
        numbers = pd.to_numeric(table[FRAME_INDEX], errors="coerce").to_numpy(dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(numbers) | (numbers < 0) | (numbers != np.round(numbers)))
        if bad.size:
            row = int(bad[0])
            raise SeesysError(
                f"{path}: row {row + 2}: {FRAME_INDEX} {table[FRAME_INDEX].iloc[row]!r} is not a "
                f"frame index (a non-negative integer)"
            )
        frames = numbers.astype(np.int64)
    thresholds, probabilities = _read_head(path, table)
    return EstimateLog(values["timestamp"], values["error_m"], frames, thresholds, probabilities)


def _read_head(path: Path, table: pd.DataFrame) -> tuple[tuple[float, ...], np.ndarray | None]:
    """The head's thresholds (increasing) and probabilities of the log's ``p_ge_*`` columns; raises a
    SeesysError naming the file, the column and the row of a probability outside [0, 1]."""
    columns = sorted((t, c) for c in table.columns if (t := column_threshold(str(c))) is not None)
    if not columns:
        return (), None
    thresholds = tuple(t for t, _ in columns)
    if len(set(thresholds)) != len(thresholds) or not all(np.isfinite(thresholds)) or thresholds[0] <= 0:
        raise SeesysError(f"{path}: head columns {[c for _, c in columns]} are not of distinct positive thresholds")
    probabilities = np.column_stack([pd.to_numeric(table[c], errors="coerce").to_numpy(np.float64) for _, c in columns])
    bad = np.argwhere(~((probabilities >= 0) & (probabilities <= 1)))
    if bad.size:
        row, k = (int(v) for v in bad[0])
        raise SeesysError(
            f"{path}: row {row + 2}: {columns[k][1]} {table[columns[k][1]].iloc[row]} is not a probability"
        )
    return thresholds, probabilities
