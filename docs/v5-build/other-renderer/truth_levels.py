"""The true error of the out-of-domain sessions' windows, per session and pooled: how many windows, their median
and the shares at or above Equation 2's alpha and its top class boundary, from evaluate's predictions.csv (every
row is judged on the same windows; the motion row's are read).

    .venv/bin/python docs/v5-build/other-renderer/truth_levels.py EVALUATE/predictions.csv --out truth_levels.csv
"""

import argparse
from pathlib import Path

import pandas as pd

from seesys.core.exceedance import class_boundaries_m
from seesys.io.core_settings import load_pulse_settings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("predictions", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    boundaries = class_boundaries_m(load_pulse_settings())
    alpha, top = boundaries[0], boundaries[-1]
    predictions = pd.read_csv(args.predictions)
    windows = predictions[predictions.set.str.startswith("session ") & (predictions.row == "motion_isotonic")]
    windows = windows[windows["round"] == windows["round"].min()]
    groups = [("all sessions", windows), *windows.groupby("run")]
    rows = [
        {
            "sessions": name,
            "windows": len(group),
            "true_median_m": group.true_m.median(),
            "share_at_or_above_alpha": (group.true_m >= alpha).mean(),
            "share_at_or_above_top": (group.true_m >= top).mean(),
            "alpha_m": alpha,
            "top_m": top,
        }
        for name, group in groups
    ]
    pd.DataFrame(rows).to_csv(args.out, index=False)
    print(pd.DataFrame(rows).to_string(index=False))


if __name__ == "__main__":
    main()
