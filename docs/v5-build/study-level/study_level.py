"""Why a forest reads the simulated study's small errors high: the pilot's channels beside the final split's
training windows of the same error range, and the build's label level beside the v4 build's.

Writes three tables:
- ``--labels``: the median label per camera, room and motion of BUILD against the v4 build's
  (docs/v4-build/dataset/label_summary.csv): is this build's error at another level?
- ``--channels``: per RTS channel, the median over the pilot's windows of each window's mean, the same over the
  reference windows (the final split's training windows of the ideal camera whose label lies between the pilot's 10th
  and 90th percentile), where the pilot's median falls among the reference windows (percentile), and, for each
  ``--model``, its median ratio on the pilot when that one channel of every pilot window is shifted by the difference
  of the two medians (every other channel as it was): which channel carries a model's reading of the task.
- printed: each model's median ratio on the pilot and on the reference windows.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.artefact.transforms import LabelTransform
from estimator.dataset.splits import read_splits
from estimator.dataset.store import SAMPLES_CSV, read_run_info
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import concat, session_windows, split_windows
from estimator.deepsee.predictors import load_predictor
from seesys.core.rts_schema import CHANNEL_NAMES
from seesys.io.core_settings import load_window_config
from study.sessions import done_attempts

KEYS = ["camera_model", "environment", "motion_group"]
V4_LABELS = Path(__file__).resolve().parents[2] / "v4-build" / "dataset" / "label_summary.csv"


def label_levels(build: Path) -> pd.DataFrame:
    """The median labelled error (mm) of each camera, room and motion of ``build`` beside the v4 build's."""
    records = []
    for run in sorted((build / "runs").iterdir()):
        info = read_run_info(run)
        if info is None:  # not finished: no labels
            continue
        samples = pd.read_csv(run / SAMPLES_CSV)
        errors = samples.error_m[samples.status == "labelled"].to_numpy() * 1000.0
        records.append({**{k: getattr(info, k) for k in KEYS}, "errors": errors})
    runs = pd.DataFrame(records)
    rows = [
        {**dict(zip(KEYS, key)), "median_mm": float(np.median(np.concatenate(group.errors.tolist())))}
        for key, group in runs.groupby(KEYS)
    ]
    v4 = pd.read_csv(V4_LABELS)[[*KEYS, "median_mm"]].rename(columns={"median_mm": "v4_median_mm"})
    table = pd.DataFrame(rows).merge(v4, on=KEYS)
    return table.assign(ratio=table.median_mm / table.v4_median_mm)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pilot", type=Path)
    parser.add_argument("build", type=Path)
    parser.add_argument("final_splits", type=Path)
    parser.add_argument("--model", action="append", required=True, metavar="NAME=MODEL")
    parser.add_argument("--labels", type=Path, required=True)
    parser.add_argument("--channels", type=Path, required=True)
    args = parser.parse_args()

    labels = label_levels(args.build)
    labels.to_csv(args.labels, index=False)
    print(
        f"label level against the v4 build: median ratio {labels.ratio.median():.3f} "
        f"({labels.ratio.min():.2f}-{labels.ratio.max():.2f}) over {len(labels)} cells"
    )

    config, window_config = load_estimator_config(), load_window_config()
    transform = LabelTransform(config.label_transform.k)
    sessions = [a for phase in sorted(args.pilot.glob("participants/*/task-seesys")) for a in done_attempts(phase)]
    pilot = concat([session_windows(s, window_config, labelled=True) for s in sessions])
    train = split_windows([args.build], read_splits(args.final_splits, [args.build]), 0, ("train",))["train"]
    camera = train.meta.camera_model.to_numpy()
    low, high = np.percentile(pilot.error_m, [10, 90])
    reference = train.subset(np.flatnonzero((camera == "ideal") & (train.error_m >= low) & (train.error_m <= high)))
    truth = float(np.median(pilot.error_m))
    print(
        f"pilot: {len(pilot)} windows, median {truth * 1e3:.2f} mm (p10-p90 {low * 1e3:.2f}-{high * 1e3:.2f}); "
        f"reference: {len(reference)} windows, median {np.median(reference.error_m) * 1e3:.2f} mm"
    )
    models = {}
    for entry in args.model:
        name, _, path = entry.partition("=")
        models[name] = load_predictor(Path(path), transform, config.evaluation.batch_size)
        on_reference = np.median(models[name].metres(reference)) / np.median(reference.error_m)
        on_pilot = np.median(models[name].metres(pilot)) / truth
        print(f"{name}: median ratio {on_pilot:.2f} on the pilot, {on_reference:.2f} on the reference windows")

    pilot_means, reference_means = pilot.rts.mean(axis=1), reference.rts.mean(axis=1)
    rows = []
    for c, channel in enumerate(CHANNEL_NAMES):
        pilot_median, reference_median = np.median(pilot_means[:, c]), np.median(reference_means[:, c])
        row = {
            "channel": channel,
            "pilot_median": float(pilot_median),
            "reference_median": float(reference_median),
            "pilot_percentile_in_reference": float(np.mean(reference_means[:, c] < pilot_median) * 100.0),
        }
        shifted = pilot.rts.copy()
        shifted[..., c] += reference_median - pilot_median
        for name, model in models.items():
            row[f"{name}_ratio_shifted"] = float(np.median(model.metres(pilot.with_rts(shifted))) / truth)
        rows.append(row)
    pd.DataFrame(rows).to_csv(args.channels, index=False)
    print(f"{args.labels}, {args.channels}")


if __name__ == "__main__":
    main()
