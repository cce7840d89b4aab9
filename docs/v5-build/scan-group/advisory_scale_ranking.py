"""How each row of an evaluation ranks the windows' errors on the advisory's scale, beside AURG as evaluate reports it.

AURG follows the mean true error of the windows kept as the largest estimates are removed, so a handful of metre-scale
windows (ORB-SLAM3 reporting tracking across a jump of its map) can hold most of a set's summed error, and whichever row
removes those first gains most of the AURG. A map jump is in the estimated trajectory, so the window's relative motion,
the motion row's input, shows it. Equation 2 gives every error from β on the same class, so for the advisory a window's
error counts up to β: here AURG to the top class (the truth capped at β, ``capped_aurg`` of
estimator.deepsee.yardsticks, which evaluate reports as ``aurg_capped``) beside AURG, each row paired with the motion
row on the same windows, with the evaluation's bootstrap over runs (configs/estimator.toml). Diagnostic only: it chooses
nothing.

    python docs/v5-build/scan-group/advisory_scale_ranking.py PREDICTIONS --out advisory_scale_ranking.csv

PREDICTIONS: the ``predictions.csv`` that ``seesys estimator evaluate`` writes (set, row, round, run, frame_index,
true_m, estimate_m).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.metrics import bootstrap_settings
from estimator.deepsee.yardsticks import Judged, capped_aurg, paired_differences, sparsification

AGAINST = "motion_isotonic"
SKIPPED = ("constant", "always_top")  # a constant's AURG is 0 on any scale
METRE_SCALE_M = 0.1  # a window at or above it is reported as part of the tail
SCALES = ("aurg", "aurg_capped")


def _judged(windows: pd.DataFrame, estimate: str) -> Judged:
    """The windows as the yardsticks read them (no bins: only the sparsification is computed)."""
    truth, empty = windows.true_m.to_numpy(), np.zeros(0)
    return Judged(windows.run.to_numpy(), truth, windows[estimate].to_numpy(), truth, empty, empty, empty, empty, empty)


def _ranking(cap_m: float) -> Callable[[Judged], dict[str, float]]:
    def statistic(judged: Judged) -> dict[str, float]:
        return {
            "aurg": sparsification(judged.estimate_m, judged.truth_m)[1],
            "aurg_capped": capped_aurg(judged.estimate_m, judged.truth_m, cap_m),
        }

    return statistic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("predictions", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    evaluation = load_estimator_config().evaluation
    statistic = _ranking(evaluation.large_error_m)  # the cap of evaluate's aurg_capped: Equation 2's beta
    settings = bootstrap_settings(evaluation)
    predictions = pd.read_csv(args.predictions)
    rows = []
    for (name, round_), judged_set in predictions.groupby(["set", "round"], sort=False):
        motion = judged_set[judged_set.row == AGAINST][["run", "frame_index", "estimate_m"]]
        for row, windows in judged_set.groupby("row", sort=False):
            if row in SKIPPED:
                continue
            paired = windows.merge(motion, on=["run", "frame_index"], suffixes=("", "_motion"), validate="one_to_one")
            tail = paired.true_m >= METRE_SCALE_M
            result = {
                "set": name,
                "round": round_,
                "row": row,
                "windows": len(paired),
                "runs": paired.run.nunique(),
                "windows_at_or_above_0.1m": int(tail.sum()),
                "their_share_of_the_summed_error": float(paired.true_m[tail].sum() / paired.true_m.sum()),
            }
            own, other = _judged(paired, "estimate_m"), _judged(paired, "estimate_m_motion")
            figures = statistic(own)
            oracle = statistic(_judged(paired.assign(estimate_m=paired.true_m), "estimate_m"))
            points, intervals = paired_differences(own, other, statistic, SCALES, settings)
            for scale in SCALES:
                result |= {
                    scale: figures[scale],
                    f"{scale}_oracle": oracle[scale],
                    f"{scale}_minus_motion": points[scale],
                    f"{scale}_minus_motion_low": intervals[scale][0],
                    f"{scale}_minus_motion_high": intervals[scale][1],
                }
            rows.append(result)
    pd.DataFrame(rows).to_csv(args.out, index=False)


if __name__ == "__main__":
    main()
