"""The study's log of the pose-error estimates a session received (``estimates.csv``): one row per ``Estimate``
message, with the Unix time it arrived. Written by ``seesys study run`` whatever the condition, so that every
participant's trajectory can be shown with the error SEESys estimated for it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from seesys.io.logfiles import read_csv_log

ESTIMATES_CSV = "estimates.csv"
ESTIMATE_COLUMNS = ("receipt_time", "device_id", "frame_index", "timestamp", "error_m", "model_version")


def read_estimate_log(folder: Path) -> pd.DataFrame:
    """The estimate log of a session folder (empty when there is none); a row cut short by a crash is dropped."""
    path = Path(folder) / ESTIMATES_CSV
    if not path.exists():
        return pd.DataFrame(columns=list(ESTIMATE_COLUMNS))
    try:
        log = read_csv_log(path)
    except pd.errors.EmptyDataError:
        return pd.DataFrame(columns=list(ESTIMATE_COLUMNS))
    return log.dropna(subset=["receipt_time", "timestamp", "error_m"])


def wall_to_camera_offset(folder: Path) -> float:
    """Seconds to add to a Unix time of the session (the advisory's buffers, the operator's events) to get the
    camera clock: the median of the estimates' frame timestamp minus their receipt time (it includes the estimate's
    latency, tens of milliseconds). Without an estimate log both clocks are taken to be the same."""
    log = read_estimate_log(folder)
    if log.empty:
        return 0.0
    return float(np.median(log.timestamp - log.receipt_time))
