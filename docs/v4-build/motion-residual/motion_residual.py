"""A forest on what the motion row does not explain, tried on the v4 rounds (not the lockbox).

The forest is fitted, on each round's training runs, to log(error) − log(motion row's estimate) (the motion row:
the isotonic fit of the error on the motion statistic, :mod:`estimator.deepsee.references`), and estimates the
motion row's estimate × exp(its prediction). Judged on the round's test sets, on the bins of the evaluation's
predictions, beside the forest and the motion row of that evaluation; "geometric mean" is √(forest × this).

    .venv/bin/python docs/v4-build/motion-residual/motion_residual.py BUILD SPLITS PREDICTIONS

BUILD: the v4 build; SPLITS: its rounds' splits (splits.json); PREDICTIONS: `seesys estimator evaluate`'s
predictions.csv of those rounds (the forest and the reference rows).
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.splits import read_splits
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import split_windows
from estimator.deepsee.forest import fit_random_forest, window_statistics
from estimator.deepsee.metrics import bootstrap_settings, judged
from estimator.deepsee.references import MOTION_ISOTONIC, fit_references, motion_statistic
from estimator.deepsee.yardsticks import paired_differences, yardsticks
from seesys.io.core_settings import load_pulse_settings

FOREST, RESIDUAL, GEOMETRIC = "random_forest", "motion_residual_forest", "geometric_mean"
FLOOR_M = 1e-4  # the motion row's estimate below which the ratio is not taken (0.1 mm)


def residual_estimates(roots: list[Path], splits_path: Path, rounds: list[int]) -> pd.DataFrame:
    splits, config, pulses = read_splits(splits_path, roots), load_estimator_config(), load_pulse_settings()
    tables = []
    for r in rounds:
        windows = split_windows(roots, splits, r, ("train", "test"))
        train, test = windows["train"], windows["test"]
        motion = fit_references(train, pulses).motion_fit
        train_motion = np.maximum(motion.predict(motion_statistic(train.rts)), FLOOR_M)
        target = np.log(np.maximum(train.error_m, FLOOR_M / 10)) - np.log(train_motion)
        forest = fit_random_forest(train.rts, target, config.random_forest, config.seed, jobs=1)
        test_motion = np.maximum(motion.predict(motion_statistic(test.rts)), FLOOR_M)
        table = test.meta[["run", "frame_index"]].assign(round=r)
        table[RESIDUAL] = test_motion * np.exp(forest.predict(window_statistics(test.rts)))
        tables.append(table)
    return pd.concat(tables, ignore_index=True)


def main() -> None:
    build, splits_path, predictions_path = (Path(a) for a in sys.argv[1:4])
    predictions = pd.read_csv(predictions_path)
    residual = residual_estimates([build], splits_path, sorted(predictions["round"].unique()))
    pulses, evaluation = load_pulse_settings(), load_estimator_config().evaluation
    settings = bootstrap_settings(evaluation)

    def score(j):
        return yardsticks(j, pulses.max_pulses + 1, evaluation.large_error_m)

    names = ("kappa", "aurg", "agreement")
    rows = [RESIDUAL, GEOMETRIC, FOREST, MOTION_ISOTONIC]
    for (r, part), group in predictions.groupby(["round", "set"]):
        wide = group.pivot_table(index=["run", "frame_index"], values="estimate_m", columns="row").reset_index()
        truth = group[group.row == FOREST][["run", "frame_index", "true_m", "timestamp"]]
        wide = wide.merge(truth, on=["run", "frame_index"]).merge(
            residual[residual["round"] == r].drop(columns="round"), on=["run", "frame_index"]
        )
        wide[GEOMETRIC] = np.sqrt(wide[FOREST] * wide[RESIDUAL])
        wide = wide.dropna(subset=rows).sort_values(["run", "frame_index"])
        meta = wide[["run", "timestamp"]]
        judgedrows = {
            k: judged(meta, wide[k].to_numpy(), wide.true_m.to_numpy(), np.zeros(len(wide)), pulses) for k in rows
        }
        print(f"round {r}, {part} ({wide.run.nunique()} runs, {len(wide)} windows)")
        for k in rows:
            s = score(judgedrows[k])
            print(f"  {k:24s} κ {s['kappa']:.3f}  AURG {s['aurg']:.3f}")
        for k in (RESIDUAL, GEOMETRIC):
            for base in (FOREST, MOTION_ISOTONIC):
                point, ci = paired_differences(judgedrows[k], judgedrows[base], score, names, settings)
                print(
                    f"  {k} − {base}: κ {point['kappa']:+.3f} [{ci['kappa'][0]:+.3f}, {ci['kappa'][1]:+.3f}], "
                    f"AURG {point['aurg']:+.3f} [{ci['aurg'][0]:+.3f}, {ci['aurg'][1]:+.3f}]"
                )


if __name__ == "__main__":
    main()
