"""Estimate logs (CSV with columns ``timestamp,error_m``), the input of ``render`` and ``replay``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core.errors import SeesysError

COLUMNS = ("timestamp", "error_m")


@dataclass(frozen=True)
class EstimateLog:
    timestamps: np.ndarray  # seconds, non-decreasing
    errors_m: np.ndarray


def read_estimate_log(path: Path) -> EstimateLog:
    """Read and validate an estimate log; a problem raises a SeesysError naming the file and the row."""
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
            raise SeesysError(f"{path}: row {row + 2}: {column} {table[column].iloc[row]!r} is not a valid "
                              f"{'non-negative number of metres' if column == 'error_m' else 'time in seconds'}")
        values[column] = numbers
    backwards = np.flatnonzero(np.diff(values["timestamp"]) < 0)
    if backwards.size:
        raise SeesysError(f"{path}: row {int(backwards[0]) + 3}: timestamps go backwards")
    return EstimateLog(values["timestamp"], values["error_m"])
