"""Label spread of rendered sequences under real ORB-SLAM3: per run and per batch, the 10-frame translation RPE
of tracked frames (median, p90, p99, share above 4 / 12 mm, share tracked) and the RTS window features with the
largest |Spearman ρ| against the label. The label-spread targets of configs/dataset.toml ([targets]) are checked per
batch.

Run it with the CPU to itself, after rendering (never while rendering):

    .venv/bin/python benchmarks/synth_label_spread.py SEQ_DIR... [--mode rgbd] [--trials 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from seesys.core.labels import LabelStatus, LabelSummary
from seesys.core.rts_schema import CHANNEL_NAMES
from seesys.io.core_settings import load_label_config
from seesys.io.rts_log import RTS_CSV
from seesys.io.session_labels import label_session
from slam_monitor.device_worker import ObserverSpec, SessionOptions
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.supervisor import run_supervised_session

THRESHOLDS_M = (0.004, 0.012)
WINDOW = 10


def run_and_label(sequence: Path, mode: SlamMode, out: Path) -> pd.DataFrame:
    observer = ObserverSpec("slam_monitor.monitor:create_observer", {"stream": False, "device_id": None})
    run_supervised_session(SessionOptions(f"tum:{sequence}", mode, out, observers=(observer,)))
    labels = label_session(out, mode is SlamMode.MONO, load_label_config()).to_frame()
    rts = pd.read_csv(out / RTS_CSV)
    table = labels.join(rts[list(CHANNEL_NAMES)].reset_index(drop=True))
    # Window features over the 10 frames of the label's pair: mean and minimum of each channel.
    for name in CHANNEL_NAMES:
        table[f"{name}_mean10"] = table[name].rolling(WINDOW, min_periods=WINDOW).mean()
        table[f"{name}_min10"] = table[name].rolling(WINDOW, min_periods=WINDOW).min()
    return table


def describe(labels: pd.DataFrame) -> str:
    s = LabelSummary.of(labels, THRESHOLDS_M)
    return (
        f"tracked {100 * s.tracked_fraction:5.1f} %  labelled {s.labelled:5d}  median {1000 * s.median_m:6.1f} mm  "
        f"p90 {1000 * s.p90_m:6.1f}  p99 {1000 * s.p99_m:6.1f}  max {1000 * s.max_m:6.1f}  "
        f">4 mm {100 * s.fraction_above[0.004]:5.1f} %  >12 mm {100 * s.fraction_above[0.012]:5.1f} %"
    )


def correlations(table: pd.DataFrame) -> pd.Series:
    ok = table[table.status == LabelStatus.LABELLED.value]
    features = [c for c in table.columns if c not in ("timestamp", "error_m", "status", "scale")]
    rho = {}
    for name in features:
        x = ok[name].to_numpy(float)
        keep = np.isfinite(x)
        if keep.sum() > 30 and np.ptp(x[keep]) > 0:
            rho[name] = spearmanr(x[keep], ok["error_m"].to_numpy()[keep]).statistic
    return pd.Series(rho).sort_values(key=np.abs, ascending=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="+", type=Path)
    parser.add_argument("--mode", choices=[m.value for m in SlamMode], default=SlamMode.RGBD.value)
    parser.add_argument("--trials", type=int, default=2)
    parser.add_argument("--out", type=Path, help="keep the session folders here (default: a temporary folder)")
    args = parser.parse_args()
    mode = SlamMode(args.mode)
    print(f"mode {mode.value}, {args.trials} trial(s), load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        tables = []
        for sequence in args.sequences:
            for trial in range(args.trials):
                table = run_and_label(sequence, mode, root / f"{sequence.name}_{mode.value}_{trial}")
                print(f"{sequence.name:32s} trial {trial}: {describe(table)}")
                tables.append(table)
        batch = pd.concat(tables, ignore_index=True)
        print(f"{'BATCH':32s}        : {describe(batch)}")
        print("strongest RTS features (Spearman ρ with the label, labelled frames pooled):")
        for name, rho in correlations(batch).head(8).items():
            print(f"  {name:40s} {rho:+.2f}")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
