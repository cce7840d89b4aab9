"""ORB-SLAM3 track time per frame on the embedded sample: median and p90, RGB-D and monocular.

The time is that of the ``track_rgbd`` / ``track_monocular`` call alone, as logged in ``frames.csv``
(``track_ms``); loading frames, pacing and logging are outside it. Runs the real device worker
(supervised child process) with the shipped configuration.

    .venv/bin/python benchmarks/track_speed.py [--source tum:data/sample] [--runs 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core import session_layout
from slam_monitor.device_worker import SessionOptions
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.supervisor import run_supervised_session

REPO = Path(__file__).resolve().parent.parent


def measure(source: str, mode: SlamMode, runs: int) -> np.ndarray:
    times = []
    for run in range(runs):
        with tempfile.TemporaryDirectory() as folder:
            run_supervised_session(SessionOptions(source, mode, Path(folder) / f"run{run}"))
            times.append(pd.read_csv(Path(folder) / f"run{run}" / session_layout.FRAMES_CSV)["track_ms"].to_numpy())
    return np.concatenate(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default=f"tum:{REPO / 'data' / 'sample'}")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    print(f"source {args.source}, {args.runs} runs per mode, {platform.machine()}, {os.cpu_count()} CPUs")
    print("| mode | frames | median ms | p90 ms | max ms |")
    print("|---|---|---|---|---|")
    for mode in SlamMode:
        ms = measure(args.source, mode, args.runs)
        print(f"| {mode.value} | {len(ms)} | {np.median(ms):.1f} | {np.percentile(ms, 90):.1f} | {ms.max():.1f} |")


if __name__ == "__main__":
    main()
