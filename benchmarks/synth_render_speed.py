"""Rendering speed of `seesys synth render`: frames/s at 640x480 with motion blur, on 1 and 2 processes.

Times the whole pipeline of a frame (ray casting, mip-mapped textures, shading, motion blur from the true
motion, sensor noise, writing the gray and depth PNGs) plus the process start-up, for one rapid-motion sequence
(the most blur samples) and one patrol sequence.

    .venv/bin/python benchmarks/synth_render_speed.py [--frames 150]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from synth.config import load_synth_config
from synth.sequence import SequenceSpec, render_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150)
    args = parser.parse_args()
    config = load_synth_config()
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print("| environment | motion | processes | frames | frames/s | mean blur streak p99 (px) |")
    print("|---|---|---|---|---|---|")
    for env, motion in (("office", "patrol"), ("workshop", "rapid")):
        for processes in (1, 2):
            spec = SequenceSpec(env, motion, 0, frames=args.frames)
            with tempfile.TemporaryDirectory() as folder:
                start = time.perf_counter()
                records = render_sequence(spec, config, Path(folder), processes, show_progress=False)
                seconds = time.perf_counter() - start
            streak = np.mean([r.blur_p99_px for r in records])
            print(f"| {env} | {motion} | {processes} | {len(records)} | {len(records) / seconds:.1f} | {streak:.1f} |")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
