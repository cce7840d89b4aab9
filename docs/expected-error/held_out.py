"""The forest row on rooms and cameras it never saw, on a build whose renders were tracked several times.

For each room of BUILD (and then each camera model), the random forest of `seesys estimator train --row
random_forest` (the same features, label transform and settings, configs/estimator.toml) and the motion row are
fitted on the build's other rooms (cameras) and judged on this one's runs, beside the same forest fitted to what the
motion row does not explain (log error − log of the motion row's estimate, estimating the motion row's estimate
times exp of its prediction: the construction of docs/v4-build/motion-residual/), the served model and the ceiling
(the mean error of the other trials of the same render, as `seesys estimator evaluate` computes it), on the windows
where the ceiling has a value, with bootstrap intervals over runs and the paired differences from the motion row.

    .venv/bin/python docs/expected-error/held_out.py BUILD [MODEL]
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.store import WITH_SAMPLES, DatasetReader, list_runs
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import reader_windows
from estimator.deepsee.forest import fit_random_forest, window_statistics
from estimator.deepsee.metrics import bootstrap_settings, judged
from estimator.deepsee.predictors import load_predictor
from estimator.deepsee.references import MOTION_ISOTONIC, ceiling_estimates, fit_references, motion_statistic
from estimator.deepsee.yardsticks import bootstrap_over_runs, paired_differences, yardsticks
from seesys.io.core_settings import load_pulse_settings

FOREST, RESIDUAL, SERVED, CEILING = "forest_trained_here", "residual_forest_here", "served_model", "ceiling"
FLOOR_M = 1e-4  # the motion row's estimate below which the ratio is not taken (0.1 mm)
NAMES = ("kappa", "aurg", "partial_spearman")


def main() -> None:
    build = Path(sys.argv[1])
    model = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("data/models/forest.onnx")
    config, pulses = load_estimator_config(), load_pulse_settings()
    settings = bootstrap_settings(config.evaluation)
    transform = LabelTransform(config.label_transform.k)
    infos = [info for info in list_runs(build) if info.status in WITH_SAMPLES]
    what = pd.DataFrame(
        [(i.environment, i.camera_model) for i in infos], index=[i.run for i in infos], columns=["room", "camera"]
    )
    windows = reader_windows(DatasetReader([build], usable_only=True))
    served = load_predictor(model, transform, config.evaluation.batch_size).metres(windows)
    ceiling = ceiling_estimates([build], windows)
    print(f"{build}: {len(infos)} runs, {len(windows)} windows; served model {model}")

    def score(j):
        return yardsticks(j, pulses.max_pulses + 1, config.evaluation.large_error_m)

    for kind in ("room", "camera"):
        of_window = windows.meta.run.map(what[kind]).to_numpy()
        for value in sorted(set(of_window)):
            train = windows.subset(np.flatnonzero(of_window != value))
            test_index = np.flatnonzero((of_window == value) & np.isfinite(ceiling))
            test = windows.subset(test_index)
            forest = fit_random_forest(
                train.rts, transform.forward(train.error_m), config.random_forest, config.seed, jobs=2
            )
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
            print(
                f"\nheld-out {kind} {value}: trained on {train.meta.run.nunique()} runs, judged on "
                f"{test.meta.run.nunique()} runs, {len(test)} windows"
            )
            print(f"  {'row':20s} {'κ':>22s} {'AURG':>22s} {'partial ρ':>22s} median ratio")
            for name, j in rows.items():
                point = score(j)
                interval, _ = bootstrap_over_runs(j, score, NAMES, settings)
                cells = [f"{point[n]:6.3f} [{interval[n][0]:6.3f}, {interval[n][1]:6.3f}]" for n in NAMES]
                print(f"  {name:20s} {' '.join(cells)} {point['median_ratio']:12.3f}")
            print("  minus the motion row, paired over runs:")
            for name in (FOREST, RESIDUAL, SERVED, CEILING):
                point, interval = paired_differences(rows[name], rows[MOTION_ISOTONIC], score, NAMES[:2], settings)
                print(
                    f"  {name:20s} Δκ {point['kappa']:+.3f} [{interval['kappa'][0]:+.3f}, {interval['kappa'][1]:+.3f}]"
                    f"  ΔAURG {point['aurg']:+.3f} [{interval['aurg'][0]:+.3f}, {interval['aurg'][1]:+.3f}]"
                )


if __name__ == "__main__":
    main()
