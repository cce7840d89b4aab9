"""Do the RTS channels see the camera? Renders of every environment preset through the ideal camera and through the
D435-like camera model, tracked by RGB-D ORB-SLAM3 with the RTS monitor and labelled; then

1. per depth-quality channel and environment, how much the two cameras' per-frame distributions overlap
   (overlapping coefficient: the shared area of the two histograms on common bins; 0 = apart, 1 = the same);
2. a random forest on RTS window statistics (the Table 3 baseline's features and settings: mean, std, min, max and
   last value of each normalised channel over the model window) trained on both cameras' renders of every
   environment but one and tested on the held-out environment's D435 render: its median estimate against the true
   median, Equation 2 class agreement and Spearman ρ, with every channel of the schema and with the colour and
   tracking channels only (the schema without its depth channels), leave-one-environment-out;
3. whether a depth layer in the PSD would add to the depth channels: the same forest with, beside every channel,
   the depth channels' definitions on each cell of a 3 × 4 grid over the depth image (hole share and σ_z/z² per
   cell, averaged over the model window), a spatial picture of the depth such as a PSD layer would give. The
   forest stands in for DeepSEE's convolutional PSD encoder, which would need the whole dataset built and trained
   again to try.

Run it with the CPU to itself (rendering and SLAM at camera pace); renders and sessions are kept in ``--out`` and
reused by a rerun, so an interrupted run resumes:

    .venv/bin/python benchmarks/camera_channels.py --out DIR [--frames 300] [--environments office,lab]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import session_windows
from estimator.deepsee.forest import fit_forest, window_statistics
from estimator.deepsee.metrics import pulse_classes
from seesys.core import rts_schema
from seesys.core.labels import LabelStatus
from seesys.io.core_settings import load_label_config, load_pulse_settings, load_window_config
from seesys.io.rts_log import read_rts_csv
from seesys.io.session_files import read_manifest
from seesys.io.session_labels import label_session
from slam_monitor.depth_features import inverse_depth, noise_over_z2
from slam_monitor.device_worker import ObserverSpec, SessionOptions
from slam_monitor.monitor_commands import MONITOR_FACTORY
from slam_monitor.monitor_config import load_monitor_config
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.sources.base import depth_metres
from slam_monitor.supervisor import run_supervised_session
from synth.config import load_synth_config
from synth.sequence import SequenceSpec, render_sequence

CAMERAS = ("ideal", "d435")
MOTION, SEED = "patrol", 5
DEPTH_CHANNELS = rts_schema.channel_names("depth")
BINS = 40
GRID = (3, 4)  # rows, columns of the depth-layer proxy's cells


def render(environment: str, camera: str, frames: int, out: Path) -> Path:
    folder = out / "renders" / f"{environment}_{camera}"
    if not (folder / "metadata.json").is_file():
        synth = load_synth_config()
        config = synth.seen_through(environment, synth.camera_model(camera))
        render_sequence(SequenceSpec(environment, MOTION, SEED, frames=frames), config, folder)
    return folder


def track(sequence: Path, out: Path) -> Path:
    session = out / "sessions" / sequence.name
    try:
        if read_manifest(session).get("status") == "completed":
            return session
    except Exception:
        pass
    observer = ObserverSpec(MONITOR_FACTORY, {"stream": False, "device_id": sequence.name, "end_stride": 1})
    run_supervised_session(
        SessionOptions(
            f"tum:{sequence}", SlamMode.RGBD, session, pace=True, wait_for_mapping=False, observers=(observer,)
        )
    )
    return session


def frame_table(session: Path, environment: str, camera: str) -> pd.DataFrame:
    labels = label_session(session, False, load_label_config()).to_frame().reset_index(drop=True)
    table = read_rts_csv(session)
    table = table.join(labels[["error_m", "status"]], on="frame_index")
    table["environment"], table["camera"] = environment, camera
    return table


def overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Overlapping coefficient of two samples' histograms on common bins."""
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if not len(a) or not len(b):
        return float("nan")
    edges = np.histogram_bin_edges(np.concatenate([a, b]), BINS)
    pa, _ = np.histogram(a, edges)
    pb, _ = np.histogram(b, edges)
    return float(np.minimum(pa / len(a), pb / len(b)).sum())


def depth_grid(sequence: Path) -> np.ndarray:
    """Per frame of a render (frames, 2 · cells): the share of pixels without depth and σ_z/z² (``depth_holes`` and
    ``depth_noise`` as the monitor defines them) on each cell of a ``GRID`` over its depth image; NaN noise in a cell
    without depth is 0, as the model's normalisation makes it."""
    depth_cfg = load_monitor_config().depth
    factor = load_synth_config().camera.depth_factor
    s = depth_cfg.stride
    rows = []
    for path in sorted((sequence / "depth").glob("*.png")):
        depth = depth_metres(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), factor)
        cells = []
        for band in np.array_split(depth, GRID[0], axis=0):
            for cell in np.array_split(band, GRID[1], axis=1):
                w = inverse_depth(cell[s // 2 :: s, s // 2 :: s])
                cells += [float(np.mean(cell == 0)), noise_over_z2(w, depth_cfg.edge_jump)]
        rows.append(cells)
    return np.nan_to_num(np.array(rows))


def held_out_forest(
    sessions: dict[tuple[str, str], Path],
    environments: list[str],
    channels: list[int],
    grids: dict[tuple[str, str], np.ndarray] | None = None,
) -> pd.DataFrame:
    """Leave-one-environment-out forest; with ``grids`` (per session, per frame: :func:`depth_grid`), each window's
    grid averaged over its frames is added to its features."""
    est = load_estimator_config()
    pulses = load_pulse_settings()
    length = load_window_config().rts_length
    # The model windows of each session, as the service forms them (windows.toml's rule), on every labelled frame.
    data = {}
    for key, session in sessions.items():
        w = session_windows(session, load_window_config(), labelled=True)
        features = window_statistics(w.rts[:, :, channels])
        if grids is not None:
            ends = w.meta.frame_index.to_numpy()
            features = np.hstack([features, np.stack([grids[key][e - length + 1 : e + 1].mean(axis=0) for e in ends])])
        data[key] = (features, w.error_m)
    rows = []
    for held in environments:
        train = [data[(e, c)] for e in environments if e != held for c in CAMERAS]
        x = np.concatenate([f for f, _ in train])
        y = np.log(np.concatenate([e for _, e in train]))
        forest = fit_forest(x, y, est.random_forest, seed=0, jobs=os.cpu_count() or 1)
        test_x, test_e = data[(held, "d435")]
        estimate = np.exp(forest.predict(test_x))
        agree = np.mean(pulse_classes(estimate, pulses) == pulse_classes(test_e, pulses))
        rows.append(
            {
                "held_out": held,
                "windows": len(test_e),
                "true_median_mm": 1000 * np.median(test_e),
                "estimate_median_mm": 1000 * np.median(estimate),
                "ratio": np.median(estimate) / np.median(test_e),
                "class_agreement": agree,
                "spearman": spearmanr(estimate, test_e).statistic,
            }
        )
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--environments", default="all", help="comma-separated presets, or all")
    args = parser.parse_args()
    presets = [p.name for p in load_synth_config().presets]
    environments = presets if args.environments == "all" else args.environments.split(",")
    print(
        f"load average at start {os.getloadavg()[0]:.2f}; {len(environments)} environments x {CAMERAS}, "
        f"{args.frames} frames, {MOTION} seed {SEED}"
    )
    tables, sessions, grids = {}, {}, {}
    for environment in environments:
        for camera in CAMERAS:
            sequence = render(environment, camera, args.frames, args.out)
            session = sessions[(environment, camera)] = track(sequence, args.out)
            tables[(environment, camera)] = frame_table(session, environment, camera)
            grids[(environment, camera)] = depth_grid(sequence)
    frames = pd.concat(tables.values(), ignore_index=True)
    frames.to_csv(args.out / "frames.csv", index=False)

    print("\nOverlap of the ideal and d435 per-frame distributions (0 = apart):")
    separation = pd.DataFrame(
        {
            env: {
                ch: overlap(tables[(env, "ideal")][ch].to_numpy(), tables[(env, "d435")][ch].to_numpy())
                for ch in DEPTH_CHANNELS
            }
            for env in environments
        }
    ).T
    print(separation.round(3).to_string())
    print("\nTrue error (10-frame RPE) median per camera, mm:")
    labelled = frames[frames.status == LabelStatus.LABELLED.value]
    print((1000 * labelled.groupby(["environment", "camera"]).error_m.median()).unstack().round(1).to_string())

    everything = list(range(rts_schema.NUM_CHANNELS))
    without_depth = [i for i, name in enumerate(rts_schema.CHANNEL_NAMES) if name not in DEPTH_CHANNELS]
    results = {}
    for name, channels, grid in (
        ("all channels", everything, None),
        ("without depth channels", without_depth, None),
        ("all channels and a 3x4 depth grid", everything, grids),
    ):
        table = held_out_forest(sessions, environments, channels, grid)
        results[name] = table
        print(f"\nRandom forest, {name}, trained on ideal + d435 of the other environments, tested on d435:")
        print(table.round(3).to_string(index=False))
        print(
            f"median ratio over held-out environments {table.ratio.median():.2f}, within x1.5 in "
            f"{int(((table.ratio > 1 / 1.5) & (table.ratio < 1.5)).sum())} of {len(table)}; class agreement "
            f"{table.class_agreement.mean():.2f}"
        )
    summary = {
        "load_average_end": os.getloadavg()[0],
        "frames": args.frames,
        "environments": environments,
        "overlap": separation.to_dict(),
        **{k: v.to_dict(orient="records") for k, v in results.items()},
    }
    (args.out / "camera_channels.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    print(f"\nload average at end {os.getloadavg()[0]:.2f}; results in {args.out / 'camera_channels.json'}")


if __name__ == "__main__":
    main()
