"""Per-frame estimates for a logged session (``seesys estimator estimate``), in the estimate-log format that
``seesys advisory render --estimates`` and ``replay`` read (advisory/estimate_log.py): ``frame_index,
timestamp, error_m``, one row per window the session's logs complete (every frame whose PSD was logged), the
estimate in metres. The frame index is written as an integer and every float in full (the shortest text that reads
back as the same number): an epoch timestamp such as 1305031102.175 keeps its milliseconds.

A model with an ordinal head adds, per window, one column per threshold, ``p_ge_<threshold in metres>`` (e.g.
``p_ge_0.004``: P(error ≥ 4 mm)), and ``head_class``, the number of them at least 0.5 (Equation 2's class where the
thresholds are its class boundaries); a model without one writes the three columns alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from estimator.deepsee.data import DataError, session_windows
from estimator.deepsee.predictors import Predictor
from seesys.core.exceedance import HEAD_CLASS_COLUMN, head_class, probability_column
from seesys.core.windows import WindowConfig


def estimate_session(predictor: Predictor, session: Path, windows: WindowConfig, out: Path) -> pd.DataFrame:
    data = session_windows(Path(session), windows, labelled=False)
    if not len(data):
        raise DataError(f"{session}: no complete model window in its monitor logs (too short, or never tracked)")
    estimates = predictor.estimates(data)
    table = pd.DataFrame(
        {
            "frame_index": data.meta.frame_index.to_numpy(np.int64),
            "timestamp": data.meta.timestamp.to_numpy(np.float64),
            "error_m": estimates.metres,
        }
    )
    if estimates.probabilities is not None:
        for k, threshold in enumerate(predictor.thresholds_m):
            table[probability_column(threshold)] = estimates.probabilities[:, k].astype(np.float64)
        table[HEAD_CLASS_COLUMN] = head_class(estimates.probabilities)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out, index=False)
    return table
