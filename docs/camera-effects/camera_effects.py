"""Which of the D435-class camera's effects makes its ORB-SLAM3 error: the same renders through the camera model
`d435` of configs/synth.toml and through copies of it with one effect removed.

`build OUT` writes the configuration in use, with the variants below added to synth.toml's camera models, into
OUT/configs, and runs `seesys dataset build` with it (``$SEESYS_CONFIG_DIR``) once per sequence and camera model, into
OUT/<room>_<motion>_<camera> (a build that exists is resumed). The renders are the same scene and trajectory
whatever the camera model (the sequence's seed does not depend on it), so each variant differs from `d435` only by
the effect it removes. Run it alone: the SLAM runs are paced at the camera rate.

`table OUT --out CSV` prints, per build, each run's median and p90 10-frame error (the label, mm) and the median over
the run's windows of the motion statistic (the motion row's input) and of some RTS channels at the window's end frame
(raw units, seesys/core/rts_schema.py), and writes them to CSV.

    .venv/bin/python docs/camera-effects/camera_effects.py build OUT [--sequences office:aiming,lab:rapid]
        [--seed 11] [--trials 2]
    .venv/bin/python docs/camera-effects/camera_effects.py table OUT --out camera_effects.csv
"""

import argparse
import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.store import DatasetReader
from estimator.deepsee.data import reader_windows
from estimator.deepsee.references import motion_statistic
from seesys.core.rts_schema import index_of
from seesys.core.units import MM_PER_M
from seesys.io.config import ConfigSet

BASE = "d435"
# Each variant: the base camera model with these fields changed (names as in synth.toml's [[camera_models]]).
VARIANTS = {
    "d435_global_shutter": {"rolling_shutter_s": 0.0},
    "d435_synchronised": {"depth_delay_s": 0.0},
    "d435_no_depth_noise": {"depth_noise_m_per_m2": 0.0},
    "d435_kinect_depth_noise": {"depth_noise_m_per_m2": 0.00143},
    "d435_steady_exposure": {
        "auto_exposure_time_constant_s": 0.0,
        "auto_exposure_damping": 1.0,
        "depth_misregistration_px": [0.0, 0.0],
    },
}
CHANNELS = (
    "depth_noise",
    "depth_registration",
    "residual_median",
    "residual_p90",
    "local_mapping_visual_error",
    "translation_sigma",
    "flow_disagreement",
)


def write_configs(destination: Path) -> Path:
    """The configuration in use, with the variants added to synth.toml's camera models, in ``destination``."""
    config = ConfigSet.read()
    models = config.sections["synth"]["camera_models"]
    (base,) = [m for m in models if m["name"] == BASE]
    for name, changes in VARIANTS.items():
        variant = copy.deepcopy(base) | changes | {"name": name}
        models[:] = [m for m in models if m["name"] != name] + [variant]
    return config.write(destination)


def build(out: Path, sequences: list[tuple[str, str]], seed: int, trials: int) -> None:
    env = dict(os.environ, SEESYS_CONFIG_DIR=str(write_configs(out / "configs")))
    seesys = Path(sys.executable).parent / "seesys"
    for room, motion in sequences:
        for camera in (BASE, *VARIANTS):
            target = out / f"{room}_{motion}_{camera}"
            command = [str(seesys), "dataset", "build", "--out", str(target), "--envs", room, "--motions", motion]
            command += ["--seeds", str(seed), "--trials", str(trials), "--cameras", camera, "--no-keep-sessions"]
            print(" ".join(command[1:]), flush=True)
            subprocess.run(command, env=env, check=True)


def table(out: Path) -> pd.DataFrame:
    rows = []
    for folder in sorted(p for p in out.iterdir() if (p / "dataset.json").exists()):
        reader = DatasetReader([folder], usable_only=True)
        windows = reader_windows(reader)
        raw = reader.rts_windows()[:, -1, :]
        runs = windows.meta.run.to_numpy()
        for run in sorted(set(runs)):
            mine = runs == run
            error_mm = windows.error_m[mine] * MM_PER_M
            row = {
                "build": folder.name,
                "run": run,
                "windows": int(mine.sum()),
                "error_median_mm": np.median(error_mm),
                "error_p90_mm": np.percentile(error_mm, 90),
                "motion_statistic": np.median(motion_statistic(windows.rts[mine])),
            }
            for name in CHANNELS:
                values = raw[mine, index_of(name)]
                values = values[np.isfinite(values)]
                row[name] = np.median(values) if len(values) else np.nan  # e.g. no depth edge to register
            rows.append(row)
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build")
    b.add_argument("out", type=Path)
    b.add_argument("--sequences", default="office:aiming,lab:rapid", help="comma-separated room:motion")
    b.add_argument("--seed", type=int, default=11)
    b.add_argument("--trials", type=int, default=2)
    t = sub.add_parser("table")
    t.add_argument("out", type=Path)
    t.add_argument("--out", dest="csv", type=Path, required=True)
    args = parser.parse_args()
    if args.command == "build":
        sequences = [tuple(s.split(":")) for s in args.sequences.split(",")]
        build(args.out, sequences, args.seed, args.trials)  # type: ignore[arg-type]
        return
    frame = table(args.out)
    frame.to_csv(args.csv, index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 20):
        print(frame.drop(columns="run").round(4).to_string(index=False))


if __name__ == "__main__":
    main()
