"""The forest row on rooms and cameras it never saw, on a build whose renders were tracked several times.

For each room of BUILD (and then each camera model), the random forest of `seesys estimator train --row
random_forest` (the same features, label transform and settings, configs/estimator.toml) and the motion row are
fitted on the build's other rooms (cameras) and judged on this one's runs, beside the same forest fitted to what the
motion row does not explain (log error − log of the motion row's estimate, estimating the motion row's estimate
times exp of its prediction: the construction of docs/v4-build/motion-residual/), the served model and the ceiling
(the mean error of the other trials of the same render, as `seesys estimator evaluate` computes it), on the windows
where the ceiling has a value, with bootstrap intervals over runs and the paired differences from the motion row.

    .venv/bin/python docs/expected-error/held_out.py BUILD --scores held_out_scores.csv [--model MODEL]
"""

import numpy as np
import pandas as pd
from expected_error import arguments, held_out_sets, judge_rows, run_table

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.store import DatasetReader
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import reader_windows
from estimator.deepsee.forest import fit_random_forest, window_statistics
from estimator.deepsee.metrics import bootstrap_settings, judged
from estimator.deepsee.predictors import load_predictor
from estimator.deepsee.references import MOTION_ISOTONIC, ceiling_estimates, fit_references, motion_statistic
from seesys.io.core_settings import load_pulse_settings

FOREST, RESIDUAL, SERVED, CEILING = "forest_trained_here", "residual_forest_here", "served_model", "ceiling"
FLOOR_M = 1e-4  # the motion row's estimate below which the ratio is not taken (0.1 mm)


def main() -> None:
    args = arguments("The forest row on rooms and cameras it did not see")
    build, model = args.build, args.model
    config, pulses = load_estimator_config(), load_pulse_settings()
    settings = bootstrap_settings(config.evaluation)
    transform = LabelTransform(config.label_transform.k)
    what = run_table(build)
    windows = reader_windows(DatasetReader([build], usable_only=True))
    served = load_predictor(model, transform, config.evaluation.batch_size).metres(windows)
    ceiling = ceiling_estimates([build], windows)
    print(f"{build}: {len(what)} runs, {len(windows)} windows; served model {model}")

    records = []
    for set_name, train_index, test_index in held_out_sets(windows, what, ceiling):
        train, test = windows.subset(train_index), windows.subset(test_index)
        target = transform.forward(train.error_m)
        forest = fit_random_forest(train.rts, target, config.random_forest, config.seed, jobs=2)
        motion_fit = fit_references(train, pulses).motion_fit
        train_motion = np.maximum(motion_fit.predict(motion_statistic(train.rts)), FLOOR_M)
        residual = fit_random_forest(
            train.rts,
            np.log(np.maximum(train.error_m, FLOOR_M / 10)) - np.log(train_motion),
            config.random_forest,
            config.seed,
            jobs=2,
        )
        motion = motion_statistic(test.rts)
        estimates = {
            MOTION_ISOTONIC: motion_fit.predict(motion),
            FOREST: transform.inverse(forest.predict(window_statistics(test.rts))),
            RESIDUAL: np.maximum(motion_fit.predict(motion), FLOOR_M)
            * np.exp(residual.predict(window_statistics(test.rts))),
            SERVED: served[test_index],
            CEILING: ceiling[test_index],
        }
        rows = {name: judged(test.meta, e, test.error_m, motion, pulses) for name, e in estimates.items()}
        where = {"set": set_name}
        records += judge_rows(rows, settings, pulses.max_pulses + 1, config.evaluation.large_error_m, where)
    pd.DataFrame(records).to_csv(args.scores, index=False)


if __name__ == "__main__":
    main()
