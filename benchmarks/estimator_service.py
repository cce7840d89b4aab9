"""Estimator service throughput and latency: 1, 4, 16 and 64 simulated devices, 1 and 2 worker processes.

Each simulated device replays a logged session's feature stream (``rts.csv`` + ``psd/``) at 30 Hz on its own
connection to ``seesys estimator serve`` (a subprocess with a private configuration: ipc:// endpoints, the
configured windows, stale limit and batching). The devices' window ends are spread evenly over one estimate period,
as independent devices' are (``--bunched``: all in the same frame period, one burst per estimate period; see
:mod:`estimator.service.simulate`). Per row it prints, over ``--seconds`` of replay:

- **latency** p50/p90/p99: feature message of a window's last frame sent → its estimate received, at the device
  (transmit + inference; the device's own preprocessing is not part of a replay);
- **estimates/s** received, against the **expected** rate: every window the replay lets form (devices × 30 /
  end_stride, less each device's first second, which no window covers yet);
- **drops**: windows dropped as stale, frames dropped at a full worker queue, frames lost in transit (the broker's
  counters, this row only), and estimates that never came;
- **CPU**: cores used by the service (broker and workers) during the row, from their CPU times.

Then, per worker count, the largest number of devices served with no drop at the full rate. The first run
records a session on the embedded sample (`seesys monitor run`, about a minute) unless ``--session`` is given,
and exports the untrained model of the configured size unless the configured one exists or ``--model`` is given.

Usage: ``.venv/bin/python benchmarks/estimator_service.py [--devices 1,4,16,64] [--workers 1,2] [--seconds 20]
[--bunched]``
(run it on a quiet machine: the figures are only as good as the CPU left to the service).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

from estimator.service.config import load_service_config
from estimator.service.sandbox import private_configs, start_service, wait_ready
from estimator.service.simulate import DeviceFleet
from estimator.service.status import query_status
from seesys.io.core_settings import load_window_config
from seesys.io.resources import resolve
from seesys.io.rts_log import read_feature_frames

RATE_HZ = 30.0
START_TIMEOUT_S = 300


def _ints(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v.strip()]


def record_session(folder: Path) -> Path:
    out = folder / "session"
    subprocess.run([sys.executable, "-m", "seesys", "monitor", "run", "--source", f"tum:{resolve('data/sample')}",
                    "--mode", "rgbd", "--pace", "--out", str(out)], check=True, stdout=subprocess.DEVNULL)
    return out


def model_file(folder: Path, given: Path | None) -> Path:
    if given is not None:
        return given
    configured = resolve(load_service_config().model)
    if configured.is_file():
        return configured
    path = folder / "deepsee-untrained.onnx"
    subprocess.run([sys.executable, "-m", "seesys", "estimator", "untrained-model", "--out", str(path)], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return path


def service_cpu_s(process: psutil.Process) -> float:
    total = 0.0
    for p in [process, *process.children(recursive=True)]:
        try:
            times = p.cpu_times()
        except psutil.NoSuchProcess:
            continue
        total += times.user + times.system
    return total


def drops(status: dict) -> dict[str, int]:
    totals = {"stale": 0, "queue_full": 0, "lost": 0}
    for device in status["devices"].values():
        totals["stale"] += device["dropped"]["stale"]
        totals["queue_full"] += device["dropped"]["queue_full"]
        totals["lost"] += device["lost_in_transit"]
    return totals


def run_row(endpoints: dict, process: psutil.Process, frames, devices: int, seconds: float, row: int,
            bunched: bool) -> dict:
    windows = load_window_config()
    fleet = DeviceFleet(endpoints["ingest"], endpoints["estimates"], [f"bench-{row}-{k}" for k in range(devices)])
    time.sleep(1.0)  # connections and subscriptions settle; frames sent before would be lost, and counted missing
    try:
        before_status, before_cpu, start = query_status(endpoints["status"], 5000), service_cpu_s(process), \
            time.perf_counter()
        result = fleet.replay(frames, seconds, RATE_HZ, windows, bunched=bunched)
        wall = time.perf_counter() - start
        cpu = service_cpu_s(process) - before_cpu
        after_status = query_status(endpoints["status"], 5000)
    finally:
        fleet.close()
    first, last = drops(before_status), drops(after_status)
    lost = {k: last[k] - first[k] for k in first}
    # Windows that can form: those whose history the replay covers (the first ones of each device cannot).
    expected = devices * len([k for k in range(int(seconds * RATE_HZ)) if k >= windows.history
                              and windows.is_psd_frame(k)])
    p50, p90, p99 = result.percentiles()
    return {"devices": devices, "p50": p50, "p90": p90, "p99": p99, "estimates_per_s": result.estimates_per_s,
            "expected_per_s": expected / seconds, "missing": max(0, expected - len(result.estimates)),
            **lost, "cores": cpu / wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--devices", type=_ints, default=[1, 4, 16, 64])
    parser.add_argument("--workers", type=_ints, default=[1, 2])
    parser.add_argument("--seconds", type=float, default=20.0, help="replay per row (default 20)")
    parser.add_argument("--session", type=Path, help="session folder to replay (default: record the sample)")
    parser.add_argument("--model", type=Path, help="ONNX model (default: configured, else an untrained stand-in)")
    parser.add_argument("--bunched", action="store_true",
                        help="all devices end their windows in the same frame period (default: spread evenly over "
                             "one estimate period, as independent devices are)")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="svcb") as tmp:
        folder = Path(tmp)
        session = args.session or record_session(folder)
        frames = list(read_feature_frames(session, "replay"))
        model = model_file(folder, args.model)
        windows = load_window_config()
        print(f"estimator service benchmark: {platform.node()}, {os.cpu_count()} CPUs, model {model.name}, session "
              f"{session} ({len(frames)} frames), {RATE_HZ:g} Hz, end_stride {windows.end_stride}, "
              f"{'bunched' if args.bunched else 'spread'} phases, "
              f"{args.seconds:g} s per row; load average before: {os.getloadavg()[0]:.2f}")
        header = (f"{'workers':>7}{'devices':>8}{'p50 ms':>8}{'p90 ms':>8}{'p99 ms':>8}{'est/s':>8}{'expected':>9}"
                  f"{'missing':>8}{'stale':>7}{'q-full':>7}{'lost':>6}{'cores':>7}")
        print(header)
        best = {}
        for workers in args.workers:
            config_dir, endpoints = private_configs(folder / f"w{workers}", connect_device_stream=False)
            log = folder / f"serve-{workers}.log"
            serve = start_service(config_dir, model, "--workers", str(workers), log=log)
            try:
                wait_ready(serve, endpoints["status"], START_TIMEOUT_S, log)
                for row, devices in enumerate(args.devices):
                    r = run_row(endpoints, psutil.Process(serve.pid), frames, devices, args.seconds, row,
                                args.bunched)
                    print(f"{workers:>7}{devices:>8}{r['p50']:>8.1f}{r['p90']:>8.1f}{r['p99']:>8.1f}"
                          f"{r['estimates_per_s']:>8.1f}{r['expected_per_s']:>9.1f}{r['missing']:>8}{r['stale']:>7}"
                          f"{r['queue_full']:>7}{r['lost']:>6}{r['cores']:>7.2f}", flush=True)
                    if r["stale"] + r["queue_full"] + r["lost"] + r["missing"] == 0:
                        best[workers] = max(best.get(workers, 0), devices)
            finally:
                serve.terminate()
                serve.wait(60)
        for workers in args.workers:
            served = best.get(workers, 0)
            print(f"{workers} worker(s): at most {served} device(s) served with no drop "
                  f"({served * RATE_HZ / windows.end_stride:.0f} estimates/s)")
        print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
