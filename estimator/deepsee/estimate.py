"""Per-frame estimates for a logged session (``seesys estimator estimate``), in the estimate-log format that
``seesys advisory render --estimates`` and ``replay`` read (advisory/estimate_log.py): ``frame_index,
timestamp, error_m``, one row per window the session's logs complete (every frame whose PSD was logged), the
estimate in metres. The frame index is written as an integer and every float in full (the shortest text that reads
back as the same number): an epoch timestamp such as 1305031102.175 keeps its milliseconds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from estimator.deepsee.data import DataError, session_windows
from estimator.deepsee.predictors import Predictor
from seesys.core.windows import WindowConfig


def estimate_session(predictor: Predictor, session: Path, windows: WindowConfig, out: Path) -> pd.DataFrame:
    data = session_windows(Path(session), windows, labelled=False)
    if not len(data):
        raise DataError(f"{session}: no complete model window in its monitor logs (too short, or never tracked)")
    table = pd.DataFrame({"frame_index": data.meta.frame_index.to_numpy(np.int64),
                          "timestamp": data.meta.timestamp.to_numpy(np.float64), "error_m": predictor.metres(data)})
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out, index=False)
    return table
