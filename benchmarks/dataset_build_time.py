"""Projected wall time of a full ``seesys dataset build`` from a measured smaller one.

Reads ``build_log.jsonl`` of a dataset folder (render frames/s; SLAM + monitor + labelling + storing seconds per
frame, start-up of each run included) and projects the default build (configs/dataset.toml: every preset × 3
motion groups × the configured duration × trials × modes):

    .venv/bin/python benchmarks/dataset_build_time.py DATASET_DIR [--frames 900] [--trials 2] [--modes 1]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from estimator.dataset.build import BUILD_LOG
from estimator.dataset.config import load_dataset_config
from estimator.synth.batch import expand_environments, expand_motions
from estimator.synth.config import load_synth_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--frames", type=int, help="frames per sequence (default: configured duration × fps)")
    parser.add_argument("--trials", type=int, help="default: configs/dataset.toml")
    parser.add_argument("--modes", type=int, help="number of SLAM modes (default: configs/dataset.toml)")
    args = parser.parse_args()
    entries = [json.loads(line) for line in (args.dataset / BUILD_LOG).read_text().splitlines() if line.strip()]
    rendered = sum(e["rendered_frames"] for e in entries)
    render_s = sum(e["render_seconds"] for e in entries if e["rendered_frames"])
    slam_frames = sum(e["slam_frames"] for e in entries)
    slam_s = sum(e["slam_seconds"] for e in entries)
    config, synth = load_dataset_config(), load_synth_config()
    sequences = (len(expand_environments(list(config.environments), synth))
                 * len(expand_motions(list(config.motions), synth)) * len(config.seeds))
    frames = args.frames or round(synth.trajectory.duration_s * synth.camera.fps)
    runs = sequences * (args.trials or config.trials) * (args.modes or len(config.modes))
    render_fps = rendered / render_s
    slam_s_per_frame = slam_s / slam_frames
    total_render = sequences * frames / render_fps
    total_slam = runs * frames * slam_s_per_frame
    print(f"measured: rendering {render_fps:.1f} frames/s ({rendered} frames on {entries[-1]['render_processes']} "
          f"processes); SLAM runs {slam_s_per_frame * 1000:.1f} ms/frame ({slam_frames} frames, "
          f"{sum(e['runs'] for e in entries)} runs; camera pace alone is {1000 / synth.camera.fps:.1f} ms)")
    print(f"projected full build: {sequences} sequences × {frames} frames, {runs} SLAM runs: render "
          f"{total_render / 60:.0f} min + SLAM {total_slam / 60:.0f} min = {(total_render + total_slam) / 3600:.2f} h")


if __name__ == "__main__":
    main()
