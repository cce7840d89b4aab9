"""Candidate D of this folder's README, the forest read with its second opinion, judged on every window of each
set of the given rounds: per window the geometric mean of the forest's estimate and the second opinion at the
window's end frame (``flow_disagreement``, mm, in metres) where that frame has one, the forest's estimate elsewhere.
The forest's and the motion row's estimates are evaluate's (``predictions.csv`` of the same build, splits and
rounds); D is scored as evaluate scores a row, paired over runs with both, and the set's ceiling κ is read from the
same evaluation's ``scores.csv``. Labelled session folders given after the splits (evaluate's ``--sessions``) are
judged pooled, for the record. Prints the rule's verdict per held-out set.

    .venv/bin/python docs/v5-build/forest-second-opinion/blend_row.py BUILD SPLITS [SESSION ...] --rounds 0,1 \
        --evaluate EVALUATE --out blend_row.csv --differences blend_differences.csv --cameras blend_cameras.csv
"""

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.splits import TEST_TRAJECTORIES, read_splits, set_indices
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import Windows, concat, normalised, reader_windows, session_raw_windows, split_readers
from estimator.deepsee.evaluate import OUT_OF_DOMAIN, paired_difference_values, predicted_estimates
from estimator.deepsee.metrics import bootstrap_settings, judged, score
from estimator.deepsee.references import CEILING, MOTION_ISOTONIC, motion_statistic
from estimator.deepsee.rows import RANDOM_FOREST
from estimator.deepsee.yardsticks import median_ratio
from seesys.core import rts_schema
from seesys.io.core_settings import load_pulse_settings, load_window_config

ROW = "forest_second_opinion"
CHANNEL = rts_schema.CHANNEL_NAMES.index("flow_disagreement")
#: What the rule asks of D on each held-out set.
KAPPA_OF_CEILING = 0.8
RATIO_RANGE = (0.8, 1.25)


def blend(forest_m: np.ndarray, second_opinion_m: np.ndarray) -> np.ndarray:
    """The geometric mean of the two where the second opinion is known, the forest's estimate elsewhere."""
    known = np.isfinite(second_opinion_m)
    return np.where(known, np.sqrt(forest_m * np.where(known, second_opinion_m, 0.0)), forest_m)


def rule_verdict(table: pd.DataFrame, differences: pd.DataFrame, cameras: pd.DataFrame) -> pd.DataFrame:
    """Each point of the rule on each held-out set (not the test trajectories or the sessions), from the tables
    :func:`main` writes."""
    low, high = RATIO_RANGE
    verdicts = []
    for _, d in table[(table.row == ROW) & ~table.set.isin([TEST_TRAJECTORIES, OUT_OF_DOMAIN])].iterrows():
        at = (differences.set == d.set) & (differences["round"] == d["round"])
        compared = differences[at].set_index("against")
        ratios = cameras[(cameras.set == d.set) & (cameras["round"] == d["round"]) & (cameras.row == ROW)]
        verdicts.append(
            {
                "set": d.set,
                "round": d["round"],
                **{
                    f"{stat}_over_{against}": bool(compared.loc[against, f"{stat}_low"] > 0)
                    for against in (MOTION_ISOTONIC, RANDOM_FOREST)
                    for stat in ("kappa", "aurg")
                },
                "kappa_of_ceiling": bool(d.kappa_of_ceiling >= KAPPA_OF_CEILING),
                "ratios_within": bool(ratios.median_ratio.between(low, high).all()),
            }
        )
    return pd.DataFrame(verdicts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("splits", type=Path)
    parser.add_argument("sessions", type=Path, nargs="*")
    parser.add_argument("--rounds", default="0,1")
    parser.add_argument("--evaluate", type=Path, required=True, help="evaluate's output folder")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--differences", type=Path, required=True)
    parser.add_argument("--cameras", type=Path, required=True)
    args = parser.parse_args()
    predictions = pd.read_csv(args.evaluate / "predictions.csv")
    evaluated = pd.read_csv(args.evaluate / "scores.csv")
    config, pulses = load_estimator_config(), load_pulse_settings()
    splits = read_splits(args.splits, [args.build])
    windows = load_window_config()
    sessions = (
        concat([session_raw_windows(s, windows, labelled=True) for s in args.sessions]) if args.sessions else None
    )
    records, cameras, differences = [], [], []
    for r in map(int, args.rounds.split(",")):
        test = split_readers([args.build], splits, r, ("test",))["test"]
        data, raw_rts = reader_windows(test), test.rts_windows()
        sets: dict[str, tuple[Windows, np.ndarray]] = {
            name: (data.subset(rows), raw_rts[rows])
            for name, rows in set_indices(data.meta, *splits.heldout(r)).items()
        }
        if sessions is not None:
            sets[OUT_OF_DOMAIN] = (normalised(sessions), sessions.rts)
        for name, (part, raw) in sets.items():
            second_opinion = raw[:, -1, CHANNEL].astype(float) / 1000.0
            estimates = {
                row: predicted_estimates(predictions, {"set": name, "row": row, "round": r}, part)
                for row in (MOTION_ISOTONIC, RANDOM_FOREST)
            }
            estimates[ROW] = blend(estimates[RANDOM_FOREST], second_opinion)
            motion = motion_statistic(part.rts)
            windows_of = {row: judged(part.meta, v, part.error_m, motion, pulses) for row, v in estimates.items()}
            for against in (MOTION_ISOTONIC, RANDOM_FOREST):
                compared = paired_difference_values(
                    windows_of[ROW],
                    windows_of[against],
                    pulses.max_pulses + 1,
                    config.evaluation.large_error_m,
                    bootstrap_settings(config.evaluation),
                )
                differences.append({"set": name, "round": r, "row": ROW, "against": against, **compared})
            ceiling = evaluated[(evaluated.set == name) & (evaluated["round"] == r) & (evaluated.row == CEILING)]
            ceiling_kappa = float(ceiling.kappa.iloc[0]) if len(ceiling) else float("nan")
            share = float(np.isfinite(second_opinion).mean())
            for row, values in estimates.items():
                scores = score(part.meta, values, part.error_m, config.evaluation, pulses, motion=motion)
                records.append(
                    {
                        "set": name,
                        "round": r,
                        "row": row,
                        "second_opinion_share": share,
                        "kappa_of_ceiling": scores.kappa / ceiling_kappa,
                        **asdict(scores),
                    }
                )
                by_camera = part.meta.groupby("camera_model").groups if "camera_model" in part.meta else {}
                for camera, at in by_camera.items():
                    at = np.asarray(at)
                    ratio = median_ratio(values[at], part.error_m[at])
                    cameras.append({"set": name, "round": r, "row": row, "camera_model": camera, "median_ratio": ratio})
    table = pd.DataFrame(records)
    table.to_csv(args.out, index=False)
    pd.DataFrame(differences).to_csv(args.differences, index=False)
    pd.DataFrame(cameras).to_csv(args.cameras, index=False)
    shown = ["set", "round", "row", "windows", "runs", "second_opinion_share", "kappa", "kappa_of_ceiling", "aurg"]
    print(table[shown + ["median_ratio"]].round(3).to_string(index=False))
    shown = ["set", "round", "against", "kappa", "kappa_low", "kappa_high", "aurg", "aurg_low", "aurg_high"]
    print(pd.DataFrame(differences)[shown].round(3).to_string(index=False))
    verdict = rule_verdict(table, pd.DataFrame(differences), pd.DataFrame(cameras))
    verdict["passes"] = verdict.drop(columns=["set", "round"]).all(axis=1)
    print(verdict.to_string(index=False))
    print("D passes the rule" if verdict.passes.all() else "D does not pass the rule")


if __name__ == "__main__":
    main()
