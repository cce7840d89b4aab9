"""The forest row on rooms and cameras it never saw, on a build whose renders were tracked several times.

For each room of BUILD (and then each camera model), the random forest of `seesys estimator train --row
random_forest` (the same features, label transform and settings, configs/estimator.toml) and the motion row are
fitted on the build's other rooms (cameras) and judged on this one's runs, beside the served model and the ceiling
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

FOREST, SERVED, CEILING = "forest_trained_here", "served_model", "ceiling"
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
            estimates = {
                MOTION_ISOTONIC: fit_references(train, pulses).estimates(test)[MOTION_ISOTONIC],
                FOREST: transform.inverse(forest.predict(window_statistics(test.rts))),
                SERVED: served[test_index],
                CEILING: ceiling[test_index],
            }
            motion = motion_statistic(test.rts)
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
            for name in (FOREST, SERVED, CEILING):
                point, interval = paired_differences(rows[name], rows[MOTION_ISOTONIC], score, NAMES[:2], settings)
                print(
                    f"  {name:20s} Δκ {point['kappa']:+.3f} [{interval['kappa'][0]:+.3f}, {interval['kappa'][1]:+.3f}]"
                    f"  ΔAURG {point['aurg']:+.3f} [{interval['aurg'][0]:+.3f}, {interval['aurg'][1]:+.3f}]"
                )


if __name__ == "__main__":
    main()
