"""Models read offline on a pilot's seesys sessions, beside the constant and the motion row: how each reads the
study's task, whose error no build was made of. With ``--sessions`` instead of PILOT, on any labelled session folders
(each named by its folder), beside the ceiling too where they are SLAM trials of one recording (the same source and
mode: :func:`estimator.deepsee.references.session_ceiling_estimates`).

Each session of PILOT's `seesys` condition (its frames, monitor logs and ground truth: a simulated study keeps
them) is labelled as the study labels it (the 10-frame error, `seesys.io.session_labels`), and every window the
device logged is estimated offline by each MODEL (`seesys estimator estimate` reproduces the live estimates of the
model the pilot ran). The constant and the motion rows are fitted on the training runs of BUILD's final split
(`seesys dataset splits --final`), as for the lockbox. Each row is judged on all sessions pooled (intervals over
sessions) and on each session alone; each row is compared with the motion row (and with each --against row), paired
over sessions.

    .venv/bin/python docs/simulated-study/pilot-forest-v5/served_models.py PILOT BUILD FINAL_SPLITS \
        --model NAME=MODEL [--model NAME=MODEL ...] [--against NAME] --out served_models.csv \
        --differences differences.csv [--predictions predictions.csv]
    .venv/bin/python docs/simulated-study/pilot-forest-v5/served_models.py BUILD FINAL_SPLITS \
        --model NAME=MODEL [...] --out served_models.csv --differences differences.csv --sessions SESSION [...]

``--predictions`` writes every window's truth and each row's estimate in the layout of evaluate's
``predictions.csv`` (set "all sessions", round 0, the participant as the run).
"""

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.splits import read_splits
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import concat, session_windows, split_windows
from estimator.deepsee.evaluate import paired_difference_values, prediction_table
from estimator.deepsee.metrics import bootstrap_settings, judged, score
from estimator.deepsee.predictors import load_predictor
from estimator.deepsee.references import (
    CEILING,
    MOTION_ISOTONIC,
    fit_references,
    motion_statistic,
    session_ceiling_estimates,
)
from seesys.io.core_settings import load_pulse_settings, load_window_config
from study.sessions import done_attempts

ALL = "all sessions"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pilot", type=Path, nargs="?", help="a simulated study: its seesys sessions, by participant")
    parser.add_argument("build", type=Path)
    parser.add_argument("final_splits", type=Path)
    parser.add_argument("--model", action="append", required=True, metavar="NAME=MODEL")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--differences", type=Path, required=True)
    parser.add_argument("--against", action="append", default=[], metavar="NAME", help="also compare with this row")
    parser.add_argument("--predictions", type=Path, help="also write each window's truth and estimates here")
    parser.add_argument("--sessions", type=Path, nargs="+", help="labelled session folders instead of a pilot")
    args = parser.parse_args()
    if (args.pilot is None) == (args.sessions is None):
        parser.error("give either PILOT or --sessions")

    config, pulses, window_config = load_estimator_config(), load_pulse_settings(), load_window_config()
    settings = bootstrap_settings(config.evaluation)
    transform = LabelTransform(config.label_transform.k)
    if args.sessions:
        folders = {folder.name: folder for folder in args.sessions}
    else:  # every attempt folder is called attempt-N: the participant names it
        phases = sorted(args.pilot.glob("participants/*/task-seesys"))
        folders = {a.parts[-3]: a for phase in phases for a in done_attempts(phase)}
    each = {name: session_windows(folder, window_config, labelled=True) for name, folder in folders.items()}
    for name, windows in each.items():
        windows.meta["run"] = name
    data = concat(list(each.values()))
    train = split_windows([args.build], read_splits(args.final_splits, [args.build]), 0, ("train",))["train"]
    print(f"{len(each)} sessions, {len(data)} labelled windows; {len(train)} training windows of the final split")

    estimates = fit_references(train, pulses).estimates(data)
    for entry in args.model:
        name, _, path = entry.partition("=")
        estimates[name] = load_predictor(Path(path), transform, config.evaluation.batch_size).metres(data)
    # A pilot's sessions are closed-loop runs, each its own motion: trials of one recording only when given.
    ceiling = session_ceiling_estimates(list(folders.values()), data) if args.sessions else None
    if ceiling is not None and np.isfinite(ceiling).any():
        estimates[CEILING] = ceiling

    if args.predictions:
        tables = [prediction_table({"set": ALL, "row": row, "round": 0}, data, e) for row, e in estimates.items()]
        pd.concat(tables).to_csv(args.predictions, index=False)
    motion = motion_statistic(data.rts)
    alpha = pulses.equation2.alpha_m
    records = []
    for row, estimate in estimates.items():
        for name in (ALL, *each):
            chosen = np.ones(len(data), bool) if name == ALL else (data.meta.run == name).to_numpy()
            mask = chosen & np.isfinite(estimate)  # the ceiling: the windows another trial labelled
            scores = score(
                data.meta[mask], estimate[mask], data.error_m[mask], config.evaluation, pulses, motion=motion[mask]
            )
            # The level the windows are read at beside their truth's: the median and the share at or above alpha.
            level = {
                "true_median_m": float(np.median(data.error_m[mask])),
                "estimate_median_m": float(np.median(estimate[mask])),
                "true_share_alpha": float(np.mean(data.error_m[mask] >= alpha)),
                "estimate_share_alpha": float(np.mean(estimate[mask] >= alpha)),
            }
            records.append({"set": name, "row": row, **level, **asdict(scores)})
    pd.DataFrame(records).to_csv(args.out, index=False)

    windows_of = {
        row: judged(data.meta, estimate, data.error_m, motion, pulses)
        for row, estimate in estimates.items()
        if row != CEILING
    }
    differences = []
    for against in (MOTION_ISOTONIC, *args.against):
        for row in windows_of:
            if row == against:
                continue
            values = paired_difference_values(
                windows_of[row], windows_of[against], pulses.max_pulses + 1, config.evaluation.large_error_m, settings
            )
            differences.append({"set": ALL, "row": row, "against": against, **values})
    pd.DataFrame(differences).to_csv(args.differences, index=False)
    print(f"{args.out}, {args.differences}")


if __name__ == "__main__":
    main()
