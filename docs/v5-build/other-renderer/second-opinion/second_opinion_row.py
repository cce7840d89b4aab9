"""The second opinion's disagreement read as an error estimate, with no training: each window's
``flow_disagreement`` at its end frame (mm, the disagreement of an optical-flow + PnP estimate of the motion over the
label's 10-frame span with ORB-SLAM3's; docs/rts-features.md) in metres, judged as evaluate judges a row, beside the
motion row fitted on the round's training windows, on the windows where the channel has a value (RGB-D frames whose
second opinion succeeded). On each test set of the given rounds of a build and on labelled session folders (pooled).
With ``--predictions`` (evaluate's predictions.csv of the same build, splits, rounds and sessions), the trained rows
``--rows`` are judged on the same windows too. Each row is compared with the second opinion, paired over runs.

    .venv/bin/python docs/v5-build/other-renderer/second-opinion/second_opinion_row.py BUILD SPLITS --rounds 0,1 \
        --predictions PREDICTIONS --rows random_forest,deepsee --out second_opinion_row.csv \
        --differences second_opinion_differences.csv --cameras second_opinion_cameras.csv SESSION [SESSION ...]
"""

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.splits import read_splits, set_indices
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import concat, normalised, reader_windows, session_raw_windows, split_readers
from estimator.deepsee.evaluate import OUT_OF_DOMAIN, paired_difference_values, predicted_estimates
from estimator.deepsee.metrics import bootstrap_settings, judged, score
from estimator.deepsee.references import MOTION_ISOTONIC, fit_references, motion_statistic
from estimator.deepsee.yardsticks import median_ratio
from seesys.core import rts_schema
from seesys.io.core_settings import load_pulse_settings, load_window_config

ROW = "second_opinion"
CHANNEL = rts_schema.CHANNEL_NAMES.index("flow_disagreement")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("splits", type=Path)
    parser.add_argument("sessions", type=Path, nargs="*")
    parser.add_argument("--rounds", default="0")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--cameras", type=Path, required=True)
    parser.add_argument("--differences", type=Path, required=True)
    parser.add_argument("--predictions", type=Path)
    parser.add_argument("--rows", default="random_forest,deepsee")
    args = parser.parse_args()
    predictions = pd.read_csv(args.predictions) if args.predictions else None
    config, pulses, windows = load_estimator_config(), load_pulse_settings(), load_window_config()
    splits = read_splits(args.splits, [args.build])
    sessions = (
        concat([session_raw_windows(s, windows, labelled=True) for s in args.sessions]) if args.sessions else None
    )
    records, cameras, differences = [], [], []
    for r in map(int, args.rounds.split(",")):
        readers = split_readers([args.build], splits, r, ("train", "test"))
        references = fit_references(reader_windows(readers["train"]), pulses)
        test = readers["test"]
        normalised_test = reader_windows(test)
        raw_rts = test.rts_windows()
        index = set_indices(normalised_test.meta, *splits.heldout(r))
        sets = {name: (normalised_test.subset(rows), raw_rts[rows]) for name, rows in index.items()}
        if sessions is not None:
            sets[OUT_OF_DOMAIN] = (normalised(sessions), sessions.rts)
        for name, (data, raw) in sets.items():
            estimate = raw[:, -1, CHANNEL].astype(float) / 1000.0
            known = np.flatnonzero(np.isfinite(estimate))
            part = data.subset(known)
            motion = motion_statistic(part.rts)
            rows = {ROW: estimate[known], MOTION_ISOTONIC: references.estimates(part)[MOTION_ISOTONIC]}
            if predictions is not None:
                for row in args.rows.split(","):
                    rows[row] = predicted_estimates(predictions, {"set": name, "row": row, "round": r}, part)
            windows_of = {row: judged(part.meta, values, part.error_m, motion, pulses) for row, values in rows.items()}
            for row in windows_of:
                if row != ROW:
                    values = paired_difference_values(
                        windows_of[row],
                        windows_of[ROW],
                        pulses.max_pulses + 1,
                        config.evaluation.large_error_m,
                        bootstrap_settings(config.evaluation),
                    )
                    differences.append({"set": name, "round": r, "row": row, "against": ROW, **values})
            for row, values in rows.items():
                scores = score(part.meta, values, part.error_m, config.evaluation, pulses, motion=motion)
                records.append({"set": name, "round": r, "row": row, "of_windows": len(data), **asdict(scores)})
                if "camera_model" in part.meta:
                    for camera, at in part.meta.groupby("camera_model").groups.items():
                        at = np.asarray(at)
                        ratio = median_ratio(values[at], part.error_m[at])
                        cameras.append(
                            {"set": name, "round": r, "row": row, "camera_model": camera, "median_ratio": ratio}
                        )
    table = pd.DataFrame(records)
    table.to_csv(args.out, index=False)
    pd.DataFrame(cameras).to_csv(args.cameras, index=False)
    pd.DataFrame(differences).to_csv(args.differences, index=False)
    shown = ["set", "round", "row", "windows", "of_windows", "runs", "kappa", "aurg", "spearman", "median_ratio"]
    print(table[shown].round(3).to_string(index=False))


if __name__ == "__main__":
    main()
