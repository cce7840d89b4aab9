"""The monitor's predicted pose covariance on session folders, as an uncertainty of their labels: the share of the
labels within its 1σ and 2σ, as computed, scaled by the scale fitted on the training runs of a build's final split,
and scaled to each row's estimate (what `seesys session export-bag` publishes), beside the share a Gaussian of each
frame's covariance puts there. The same figures as `seesys dataset coverage` gives a build's test sets
(:mod:`estimator.dataset.covariance`), here on sessions no build holds.

    .venv/bin/python docs/v5-build/other-renderer/coverage.py BUILD FINAL_SPLITS --predictions PREDICTIONS \
        --out served/coverage.csv --model-scaled served/model_scaled_coverage.csv SESSION [SESSION ...]

PREDICTIONS: `served_models.py --sessions ... --predictions` (each window's estimate by each row; run = the
session folder's name).
"""

import argparse
from pathlib import Path

import pandas as pd

from estimator.dataset.covariance import (
    build_frames,
    coverage_figures,
    fitted_scale,
    model_scaled_coverage,
    read_predictions,
    session_frames,
)
from estimator.dataset.splits import read_splits
from estimator.deepsee.data import session_mode
from seesys.io.core_settings import load_label_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("final_splits", type=Path)
    parser.add_argument("sessions", type=Path, nargs="+")
    parser.add_argument("--predictions", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--model-scaled", type=Path, required=True)
    args = parser.parse_args()

    labels = load_label_config()
    train = read_splits(args.final_splits, [args.build]).rounds[0].train
    built = build_frames([args.build], labels.delta_frames)
    scale = fitted_scale(built[built.run.isin(train)])
    each = {
        folder.name: session_frames(folder, labels.delta_frames, session_mode(folder) == "mono", labels)
        for folder in args.sessions
    }
    frames = pd.concat(list(each.values()), ignore_index=True).assign(camera_model="ideal")
    rows = []
    for name, part in [("all sessions", frames), *each.items()]:
        scaled = coverage_figures(part, scale)
        rows.append(
            {
                "sessions": name,
                **coverage_figures(part),
                "scale": scale,
                "within_1sigma_scaled": scaled["within_1sigma"],
                "within_2sigma_scaled": scaled["within_2sigma"],
            }
        )
    table = pd.DataFrame(rows)
    table.to_csv(args.out, index=False)
    model_scaled = model_scaled_coverage(frames, read_predictions(args.predictions))
    model_scaled.to_csv(args.model_scaled, index=False)
    print(table.round(3).to_string(index=False))
    print(model_scaled.round(3).to_string(index=False))


if __name__ == "__main__":
    main()
