"""The labels of a dataset build per motion group and camera model: runs, share of frames tracked, and the median,
90th percentile and share at or above α (4 mm) of the usable labelled windows' 10-frame errors.

    python docs/v5-build/scan-group/group_labels.py BUILD --out group_labels.csv
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from estimator.dataset.store import RUNS_DIR, SAMPLES_CSV, read_run_info

ALPHA_M = 0.004


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    windows, runs = [], []
    for folder in sorted((args.build / RUNS_DIR).iterdir()):
        info = read_run_info(folder)
        if info is None:
            continue
        samples = pd.read_csv(folder / SAMPLES_CSV)
        usable = samples[samples.usable & (samples.status == "labelled")]
        keys = {"motion_group": info.motion_group, "camera_model": info.camera_model}
        runs.append(keys | {"tracked": info.frames_tracked / info.frames})
        windows.append(usable.assign(**keys)[["motion_group", "camera_model", "error_m"]])
    errors, tracked = pd.concat(windows), pd.DataFrame(runs)
    rows = []
    for by in (["motion_group"], ["motion_group", "camera_model"]):
        for key, group in errors.groupby(by):
            key = key if isinstance(key, tuple) else (key,)
            mask = (tracked[by] == pd.Series(key, index=by)).all(axis=1)
            rows.append(
                dict(zip(by, key))
                | {
                    "runs": int(mask.sum()),
                    "tracked_share": round(float(tracked.tracked[mask].mean()), 3),
                    "windows": len(group),
                    "median_mm": round(float(group.error_m.median()) * 1000, 2),
                    "p90_mm": round(float(group.error_m.quantile(0.9)) * 1000, 1),
                    "share_at_or_above_alpha": round(float((group.error_m >= ALPHA_M).mean()), 3),
                }
            )
    table = pd.DataFrame(rows).fillna({"camera_model": "all"})
    table[["motion_group", "camera_model", *table.columns.drop(["motion_group", "camera_model"])]].to_csv(
        args.out, index=False
    )


if __name__ == "__main__":
    main()
