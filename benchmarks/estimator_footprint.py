"""What a local estimator costs the machine it shares with a device: ``seesys estimator serve`` with one worker
process (``--workers 1``) and with the broker running the model itself (``--workers 0``, what ``seesys run --local``
starts, ``[local_estimator]`` of configs/app.toml), side by side, alternating, ``--runs`` times each:

- **start-up**: the service launched → its status endpoint answers (the model loaded, by the worker too);
- **processes and memory** of the service's process tree once it answers: resident (RSS) and unique (USS: what
  ending the service would free) memory, summed over the processes;
- **CPU** while it serves one simulated device replaying a logged session at 30 Hz for ``--seconds``, in cores
  (100 % of one core = 1.00), from the processes' CPU times, and that device's latency (window's last frame sent →
  estimate received) at p50.

The first run records a session on the embedded sample (``seesys monitor run``, about a minute) unless ``--session``
is given; the model is the configured one unless ``--model`` is given.

Usage: ``.venv/bin/python benchmarks/estimator_footprint.py [--runs 3] [--seconds 20] [--session DIR]``
(run it on a quiet machine).
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
from estimator_service import RATE_HZ, START_TIMEOUT_S, replay_inputs, service_cpu_s

from estimator.service.sandbox import private_configs, start_service, wait_ready
from estimator.service.simulate import DeviceFleet
from seesys.io.core_settings import load_window_config

LAYOUTS = (("one worker process", 1), ("the broker runs the model", 0))


def one_run(folder: Path, model: Path, frames, seconds: float, workers: int) -> dict[str, float]:
    """Start-up, processes, memory, CPU and latency of one fresh service with ``workers`` worker processes."""
    config_dir, endpoints = private_configs(folder, connect_device_stream=False)
    log = folder / "serve.log"
    started = time.monotonic()
    serve = start_service(config_dir, model, "--workers", str(workers), log=log)
    try:
        wait_ready(serve, endpoints["status"], START_TIMEOUT_S, log)
        ready_s = time.monotonic() - started
        broker = psutil.Process(serve.pid)
        processes = [broker, *broker.children(recursive=True)]
        rss = sum(p.memory_info().rss for p in processes) / 2**20
        uss = sum(p.memory_full_info().uss for p in processes) / 2**20
        fleet = DeviceFleet(endpoints["ingest"], endpoints["estimates"], ["footprint-0"])
        time.sleep(1.0)  # connections and subscriptions settle
        try:
            cpu_before, wall_before = service_cpu_s(broker), time.monotonic()
            result = fleet.replay(frames, seconds, RATE_HZ, load_window_config(), drain_s=0.5)
            cores = (service_cpu_s(broker) - cpu_before) / (time.monotonic() - wall_before)
        finally:
            fleet.close()
    finally:
        serve.terminate()
        serve.wait(60)
    return {
        "ready_s": ready_s,
        "processes": float(len(processes)),
        "rss_mb": rss,
        "uss_mb": uss,
        "cores": cores,
        "p50_ms": float(np.percentile(result.latency_ms, 50)) if result.latency_ms else float("nan"),
        "estimates": float(len(result.latency_ms)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3, help="runs of each layout, alternating (default 3)")
    parser.add_argument("--seconds", type=float, default=20.0, help="one device's replay per run (default 20)")
    parser.add_argument("--session", type=Path, help="session folder to replay (default: record the sample)")
    parser.add_argument("--model", type=Path, help="ONNX model (default: the configured one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="svcf") as tmp:
        folder = Path(tmp)
        session, frames, model = replay_inputs(folder, args.session, args.model)
        print(
            f"local estimator footprint: {platform.node()}, {os.cpu_count()} CPUs, model {model.name}, session "
            f"{session} ({len(frames)} frames) replayed by one device at {RATE_HZ:g} Hz for {args.seconds:g} s a "
            f"run, {args.runs} run(s) of each layout, alternating; load average before: {os.getloadavg()[0]:.2f}"
        )
        runs: dict[str, list[dict[str, float]]] = {name: [] for name, _ in LAYOUTS}
        for k in range(args.runs):
            for name, workers in LAYOUTS:
                runs[name].append(one_run(folder / f"r{k}w{workers}", model, frames, args.seconds, workers))
        columns = (
            ("ready_s", "ready (s)", 2),
            ("processes", "processes", 0),
            ("rss_mb", "RSS (MB)", 0),
            ("uss_mb", "USS (MB)", 0),
            ("cores", "CPU (cores)", 3),
            ("p50_ms", "p50 (ms)", 2),
            ("estimates", "estimates", 0),
        )
        print(f"\n{'layout (median of the runs; range)':<36}" + "".join(f"{label:>21}" for _, label, _ in columns))
        for name, results in runs.items():
            cells = []
            for key, _, digits in columns:
                values = [r[key] for r in results]
                cells.append(f"{np.median(values):.{digits}f} ({min(values):.{digits}f}–{max(values):.{digits}f})")
            print(f"{name:<36}" + "".join(f"{c:>21}" for c in cells))
        print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
