"""The residuals' shear (RTS schema v5) on rooms and cameras a forest did not see, with it and without it.

On BUILD (schema v5, renders tracked two or more times), for each room and then each camera model: the random forest
of `seesys estimator train --row random_forest` (the same features, label transform and settings,
configs/estimator.toml) fitted on the other rooms' (cameras') runs with every channel, and again with
`residual_shear` left out (schema v4's channels), the motion row fitted on the same runs, the served model and the
ceiling (the mean error of the other trials of the same render), judged on this room's (camera's) runs, on the
windows where the ceiling has a value, with bootstrap intervals over runs, the paired differences from the motion row
and the forest with the shear less the forest without it. Then the geometry channels alone on the same windows, as
`seesys estimator evaluate` judges them (each channel's window feature chosen on the training runs by |partial ρ|
given motion; ρ and partial ρ on the held-out runs), and the shear's median per camera model.

    .venv/bin/python docs/camera-effects/held_out_shear.py BUILD --scores held_out_shear_scores.csv \
        --channels held_out_shear_channels.csv [--model MODEL]
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "expected-error"))
from expected_error import DIFFERENCES, held_out_sets, judge_rows, run_table

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.store import DatasetReader
from estimator.deepsee.channels import channel_table, choose_features
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import reader_windows
from estimator.deepsee.evaluate import raw_set
from estimator.deepsee.forest import fit_random_forest, window_statistics
from estimator.deepsee.metrics import bootstrap_settings, judged
from estimator.deepsee.predictors import load_predictor
from estimator.deepsee.references import MOTION_ISOTONIC, ceiling_estimates, fit_references, motion_statistic
from estimator.deepsee.yardsticks import paired_differences, yardsticks
from seesys.core.rts_schema import CHANNEL_NAMES, index_of
from seesys.io.core_settings import load_pulse_settings

SHEAR = "residual_shear"
WITH, WITHOUT, SERVED, CEILING = "forest_with_shear", "forest_without_shear", "served_model", "ceiling"
PRINTED_CHANNELS = (SHEAR, "flow_disagreement", "residual_median")


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path, help="a schema v5 dataset build whose renders were tracked 2+ times")
    parser.add_argument("--scores", type=Path, required=True, help="CSV file for every yardstick printed")
    parser.add_argument("--channels", type=Path, required=True, help="CSV file for the channels judged alone")
    parser.add_argument("--model", type=Path, default=Path("data/models/forest.onnx"), help="the served model")
    return parser.parse_args()


def main() -> None:
    args = arguments()
    config, pulses = load_estimator_config(), load_pulse_settings()
    settings = bootstrap_settings(config.evaluation)
    transform = LabelTransform(config.label_transform.k)
    what = run_table(args.build)
    reader = DatasetReader([args.build], usable_only=True)
    windows, raw = reader_windows(reader), raw_set(reader)
    served = load_predictor(args.model, transform, config.evaluation.batch_size).metres(windows)
    ceiling = ceiling_estimates([args.build], windows)
    without = np.array([i for i, name in enumerate(CHANNEL_NAMES) if name != SHEAR])
    print(f"{args.build}: {len(what)} runs, {len(windows)} windows; served model {args.model}")

    shear_end = raw.rts[:, -1, index_of(SHEAR)]
    camera_of_window = windows.meta.run.map(what["camera"]).to_numpy()
    print("residual_shear at the window's end, median (px) per camera model:")
    for camera in sorted(set(camera_of_window)):
        values = shear_end[(camera_of_window == camera) & np.isfinite(shear_end)]
        print(f"  {camera:12s} {np.median(values):.3f} ({len(values)} windows)")

    def score(j):  # type: ignore[no-untyped-def]
        return yardsticks(j, pulses.max_pulses + 1, config.evaluation.large_error_m)

    records, channel_rows = [], []
    for set_name, train_index, test_index in held_out_sets(windows, what, ceiling):
        train, test = windows.subset(train_index), windows.subset(test_index)
        target = transform.forward(train.error_m)
        full = fit_random_forest(train.rts, target, config.random_forest, config.seed, jobs=2)
        reduced = fit_random_forest(train.rts[..., without], target, config.random_forest, config.seed, jobs=2)
        motion = motion_statistic(test.rts)
        estimates = {
            MOTION_ISOTONIC: fit_references(train, pulses).motion_fit.predict(motion),
            WITH: transform.inverse(full.predict(window_statistics(test.rts))),
            WITHOUT: transform.inverse(reduced.predict(window_statistics(test.rts[..., without]))),
            SERVED: served[test_index],
            CEILING: ceiling[test_index],
        }
        rows = {name: judged(test.meta, e, test.error_m, motion, pulses) for name, e in estimates.items()}
        where = {"set": set_name}
        records += judge_rows(rows, settings, pulses.max_pulses + 1, config.evaluation.large_error_m, where)
        point, interval = paired_differences(rows[WITH], rows[WITHOUT], score, DIFFERENCES, settings)
        print(
            f"  with − without the shear: Δκ {point['kappa']:+.3f} "
            f"[{interval['kappa'][0]:+.3f}, {interval['kappa'][1]:+.3f}]  ΔAURG {point['aurg']:+.3f} "
            f"[{interval['aurg'][0]:+.3f}, {interval['aurg'][1]:+.3f}]"
        )
        record: dict[str, object] = {**where, "row": WITH, "compared_with": WITHOUT}
        for n in DIFFERENCES:
            record[n], (record[f"{n}_low"], record[f"{n}_high"]) = point[n], interval[n]
        records.append(record)
        table = channel_table(raw.subset(test_index), choose_features(raw.subset(train_index)), settings)
        chosen = table[table.chosen & table.channel.isin(PRINTED_CHANNELS)]
        for _, c in chosen.iterrows():
            print(
                f"  channel {c.channel:18s} ({c.feature:5s}) ρ {c.spearman:+.3f}  partial ρ given motion "
                f"{c.partial_spearman:+.3f} [{c.partial_spearman_low:+.3f}, {c.partial_spearman_high:+.3f}]"
            )
        channel_rows.append(table.assign(set=where["set"]))
    pd.DataFrame(records).to_csv(args.scores, index=False)
    pd.concat(channel_rows).to_csv(args.channels, index=False)


if __name__ == "__main__":
    main()
