"""Projected wall time of a full ``seesys dataset build`` from a measured (smaller or interrupted) one.

Reads the render phases of ``build_log.jsonl`` (render frames/s) and the ``run.json`` of every completed run
(seconds per frame of SLAM + monitor at camera pace, labelling and windowing, start-up included) of a dataset
folder, and projects the default build (configs/dataset.toml: every preset × the configured motion groups ×
duration × trials × modes):

    .venv/bin/python benchmarks/dataset_build_time.py DATASET_DIR [--frames 900] [--trials 2] [--modes 1]
        [--render-fps F]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from estimator.dataset.build import BUILD_LOG
from estimator.dataset.config import load_dataset_config
from estimator.dataset.store import COMPLETED, list_runs
from synth.batch import expand_environments, expand_motions
from synth.config import load_synth_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--frames", type=int, help="frames per sequence (default: configured duration × fps)")
    parser.add_argument("--trials", type=int, help="default: configs/dataset.toml")
    parser.add_argument("--modes", type=int, help="number of SLAM modes (default: configs/dataset.toml)")
    parser.add_argument(
        "--render-fps",
        type=float,
        help="render speed (frames/s) to assume when the build log has no render phase (a build "
        "interrupted before builders logged it)",
    )
    args = parser.parse_args()
    log = args.dataset / BUILD_LOG
    entries = [json.loads(line) for line in log.read_text().splitlines() if line.strip()] if log.exists() else []
    renders = [e for e in entries if e.get("rendered_frames")]
    if renders:
        rendered = sum(e["rendered_frames"] for e in renders)
        render_fps = rendered / sum(e["render_seconds"] for e in renders)
        render_note = f"{render_fps:.1f} frames/s ({rendered} frames on {renders[-1]['render_processes']} processes)"
    elif args.render_fps:
        render_fps, render_note = args.render_fps, f"{args.render_fps:.1f} frames/s (assumed, --render-fps)"
    else:
        raise SystemExit(f"{log} has no render phase to time; give --render-fps")
    runs_done = [r for r in list_runs(args.dataset) if r.status == COMPLETED]
    if not runs_done:
        raise SystemExit(f"{args.dataset} has no completed SLAM run to time")
    slam_frames = sum(r.frames for r in runs_done)
    # Runs stored before run.json had ``seconds`` count only their SLAM session, not their labelling.
    slam_s = sum(r.seconds or r.slam_seconds for r in runs_done)
    config, synth = load_dataset_config(), load_synth_config()
    sequences = (
        len(expand_environments(list(config.environments), synth))
        * len(expand_motions(list(config.motions), synth))
        * len(config.seeds)
    )
    frames = args.frames or round(synth.trajectory.duration_s * synth.camera.fps)
    runs = sequences * (args.trials or config.trials) * (args.modes or len(config.modes))
    slam_s_per_frame = slam_s / slam_frames
    total_render = sequences * frames / render_fps
    total_slam = runs * frames * slam_s_per_frame
    print(
        f"measured: rendering {render_note}; SLAM runs {slam_s_per_frame * 1000:.1f} ms/frame ({slam_frames} frames, "
        f"{len(runs_done)} runs; camera pace alone is {1000 / synth.camera.fps:.1f} ms)"
    )
    print(
        f"projected full build: {sequences} sequences × {frames} frames, {runs} SLAM runs: render "
        f"{total_render / 60:.0f} min + SLAM {total_slam / 60:.0f} min = {(total_render + total_slam) / 3600:.2f} h"
    )


if __name__ == "__main__":
    main()
