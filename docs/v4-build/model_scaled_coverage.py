"""The model's estimate as an uncertainty: the share of labels within 1× and 2× a row's estimate, per round, set
and row, from `seesys estimator evaluate`'s predictions.csv (one per round folder given). Beside the pose
covariance's coverage (covariance_coverage.csv): a model that estimates the error's typical size would, read as a
σ of an isotropic 3-D Gaussian, hold 64 % of the labels within 1σ and 98.5 % within 2σ.

    .venv/bin/python docs/v4-build/model_scaled_coverage.py EVALUATE_FOLDER...
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROWS = ("deepsee", "wo_geometry", "random_forest", "motion_isotonic")

rows = []
for folder in sys.argv[1:]:
    predictions = pd.read_csv(Path(folder) / "predictions.csv")
    predictions = predictions[predictions.row.isin(ROWS) & ~predictions.set.str.startswith("session")]
    for (round_index, set_name, row), part in predictions.groupby(["round", "set", "row"]):
        ratio = part.true_m / part.estimate_m
        rows.append(
            {
                "round": round_index,
                "set": set_name,
                "row": row,
                "windows": len(part),
                "within_1x": float(np.mean(ratio <= 1)),
                "within_2x": float(np.mean(ratio <= 2)),
                "median_label_over_estimate": float(np.median(ratio)),
            }
        )
print(pd.DataFrame(rows).round(3).to_markdown(index=False))
