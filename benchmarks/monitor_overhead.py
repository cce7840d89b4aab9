"""RTS monitor overhead, in the layout of paper Table 4: the same sequence tracked by ORB-SLAM3 alone, with the
monitor, and with the monitor streaming to a listening subscriber.

Each run is a fresh worker process (``run_device_session``, paced at the camera rate as on a device). A sampler
thread reads the worker's CPU % (of one core; 200 % = two cores busy) and resident memory with psutil while it
tracks (the paper's measure, RSS, and its anonymous part, RSS less the file-backed pages: a library's code that the
monitor's first calls page in counts in RSS, though it is shared and the kernel may drop it at any time); per-frame
tracking latency is ``track_ms`` of ``frames.csv``; the monitor's own time per frame (wall and thread CPU time) and
the stream's bandwidth come from ``monitor_stats.json``. On a machine whose cores are busy with other work, CPU %
and latency differences between runs are dominated by that other work; the monitor thread's CPU time per frame is
the figure that stays put. Configurations alternate run by run so that slow drifts in machine load hit all of them
alike. Each configuration's range over the runs of its median tracking latency and median memory is printed too: the
monitor's effect is within the run-to-run noise where its range meets SLAM alone's.

In RGB-D mode it also times the depth-quality channels alone (``slam_monitor.depth_features``, schema v3) on every
frame of the source, in this process, fed the source's ground-truth motion as the tracked motion (a source without
ground truth: none, so ``depth_registration`` does not fit): wall and thread CPU time per frame, the part of the
monitor's per-frame cost they add.

    .venv/bin/python benchmarks/monitor_overhead.py [--source tum:data/sample] [--mode rgbd] [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
from rich.console import Console
from rich.table import Table

from seesys.core.session_layout import FRAMES_CSV
from seesys.io.network import load_network_config
from slam_monitor.depth_features import DepthQuality
from slam_monitor.device_worker import ObserverSpec, SessionOptions, run_device_session
from slam_monitor.monitor import MONITOR_STATS_JSON
from slam_monitor.monitor_commands import MONITOR_FACTORY
from slam_monitor.monitor_config import load_monitor_config
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.sources.registry import open_source, parse_source_spec
from slam_monitor.sources.settings import load_camera_config
from slam_monitor.stream import FeatureSubscriber
from slam_monitor.supervisor import frames_logged

REPO = Path(__file__).resolve().parent.parent
CONFIGURATIONS = {
    "SLAM": None,
    "SLAM+RTS": {"stream": False},
    "SLAM+RTS+stream": {"stream": True},
}
SAMPLE_PERIOD_S = 0.1


@dataclass
class Measurements:
    cpu_percent: list[float] = field(default_factory=list)
    memory_mb: list[float] = field(default_factory=list)
    # Resident memory less its file-backed pages (psutil's rss − shared on Linux): what the process allocated, without
    # the library code it paged in (the monitor's first calls into OpenCV, scipy and BLAS page in megabytes of it).
    anonymous_mb: list[float] = field(default_factory=list)
    track_ms: list[float] = field(default_factory=list)
    monitor: list[dict] = field(default_factory=list)
    camera_hz: float = float("nan")
    received: int = 0
    # Per run: the median tracking latency and median memory, for the run-to-run spread.
    run_latency_ms: list[float] = field(default_factory=list)
    run_memory_mb: list[float] = field(default_factory=list)
    run_anonymous_mb: list[float] = field(default_factory=list)


def _worker(options: SessionOptions) -> None:
    # ORB-SLAM3 prints to stdout and stderr: keep the benchmark's output readable (a failing worker is reported
    # by its exit code; `seesys monitor run` on the same source shows the message).
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    run_device_session(options)


def _sample(pid: int, session_dir: Path, into: Measurements, done: threading.Event) -> None:
    """CPU % and RSS of the worker from its first tracked frame (vocabulary loading and imports excluded)."""
    process = psutil.Process(pid)
    while not done.is_set() and frames_logged(session_dir) < 1:
        time.sleep(0.01)
    try:
        process.cpu_percent(None)
        while not done.wait(SAMPLE_PERIOD_S):
            into.cpu_percent.append(process.cpu_percent(None))
            memory = process.memory_info()
            into.memory_mb.append(memory.rss / 2**20)
            into.anonymous_mb.append((memory.rss - memory.shared) / 2**20)
    except psutil.NoSuchProcess:
        pass


def _listen(endpoint: str, into: Measurements, done: threading.Event) -> None:
    subscriber = FeatureSubscriber(endpoint)
    while not done.is_set():
        if subscriber.receive(timeout_ms=100) is not None:
            into.received += 1
    subscriber.close()


def run_once(name: str, source: str, mode: SlamMode, max_frames: int | None, into: Measurements) -> None:
    settings = CONFIGURATIONS[name]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "session"
        observers = (ObserverSpec(MONITOR_FACTORY, settings),) if settings is not None else ()
        options = SessionOptions(
            source=source, mode=mode, out_dir=out, max_frames=max_frames, pace=True, observers=observers
        )
        done = threading.Event()
        listener = None
        if settings and settings["stream"]:
            listener = threading.Thread(target=_listen, args=(load_network_config().features_endpoint, into, done))
            listener.start()
        memory_before = len(into.memory_mb)
        worker = multiprocessing.get_context("spawn").Process(target=_worker, args=(options,))
        worker.start()
        sampler = threading.Thread(target=_sample, args=(worker.pid, out, into, done))
        sampler.start()
        worker.join()
        done.set()
        sampler.join()
        if listener is not None:
            listener.join()
        if worker.exitcode != 0:
            raise SystemExit(f"{name}: the worker failed (exit code {worker.exitcode})")
        frames = pd.read_csv(out / FRAMES_CSV)
        into.track_ms += frames["track_ms"].tolist()
        into.run_latency_ms.append(float(frames["track_ms"].median()))
        into.run_memory_mb.append(statistics.median(into.memory_mb[memory_before:]))
        into.run_anonymous_mb.append(statistics.median(into.anonymous_mb[memory_before:]))
        into.camera_hz = 1.0 / float(np.median(np.diff(frames["timestamp"])))
        if settings is not None:
            into.monitor.append(json.loads((out / MONITOR_STATS_JSON).read_text()))


def _ratio(value: float, base: float) -> str:
    return f"{value:.1f} ({(value / base - 1) * 100:+.1f} %)"


def report(results: dict[str, Measurements], console: Console) -> dict:
    table = Table(title="RTS monitor overhead (paper Table 4 layout)")
    table.add_column("Metric")
    for name in results:
        table.add_column(name, justify="right")
    rows = {
        "Average CPU usage (%)": lambda m: statistics.fmean(m.cpu_percent),
        "Median CPU usage (%)": lambda m: statistics.median(m.cpu_percent),
        "Average memory usage (MB)": lambda m: statistics.fmean(m.memory_mb),
        "Median memory usage (MB)": lambda m: statistics.median(m.memory_mb),
        "Median anonymous memory (MB)": lambda m: statistics.median(m.anonymous_mb),
        "Average tracking latency (ms)": lambda m: statistics.fmean(m.track_ms),
        "Median tracking latency (ms)": lambda m: statistics.median(m.track_ms),
    }
    base = results["SLAM"]
    figures: dict = {}
    for label, metric in rows.items():
        values = {name: metric(m) for name, m in results.items()}
        figures[label] = values
        table.add_row(
            label,
            *[f"{values['SLAM']:.1f}" if name == "SLAM" else _ratio(v, metric(base)) for name, v in values.items()],
        )
    console.print(table)
    # Run-to-run spread of each configuration: the monitor's effect on latency and memory is within the noise when
    # its range overlaps SLAM alone's.
    for label, attribute in (
        ("median tracking latency (ms)", "run_latency_ms"),
        ("median memory (MB)", "run_memory_mb"),
        ("median anonymous memory (MB)", "run_anonymous_mb"),
    ):
        spread = {name: getattr(m, attribute) for name, m in results.items()}
        figures[f"runs: {label}"] = spread
        console.print(
            f"run to run, {label}: " + "; ".join(f"{name} {min(v):.1f}-{max(v):.1f}" for name, v in spread.items())
        )
    for name, m in results.items():
        if not m.monitor:
            continue
        ms = [s["monitor_ms_median"] for s in m.monitor]
        p90 = [s["monitor_ms_p90"] for s in m.monitor]
        run_cpu_ms = [s["monitor_cpu_ms_mean"] for s in m.monitor]
        cpu_ms = float(np.mean(run_cpu_ms))
        dropped = sum(s["frames_dropped"] for s in m.monitor)
        processed = sum(s["frames_processed"] for s in m.monitor)
        # The monitor thread's own CPU time, as a share of the SLAM-alone CPU use at the camera rate.
        core_percent = cpu_ms * m.camera_hz / 10
        cpu_share = core_percent / statistics.fmean(base.cpu_percent) * 100
        line = (
            f"{name}: monitor {np.median(ms):.2f} ms/frame median wall (p90 {np.median(p90):.2f}), "
            f"{cpu_ms:.2f} ms/frame thread CPU = {core_percent:.1f} % of a core at {m.camera_hz:.0f} Hz "
            f"(+{cpu_share:.1f} % over SLAM alone; run to run {min(run_cpu_ms):.2f}-{max(run_cpu_ms):.2f}), "
            f"{processed} frames processed, {dropped} dropped"
        )
        figures[name] = {
            "monitor_ms_median": float(np.median(ms)),
            "monitor_ms_p90": float(np.median(p90)),
            "monitor_cpu_ms_mean": cpu_ms,
            "monitor_cpu_ms_runs": run_cpu_ms,
            "monitor_cpu_share_percent": cpu_share,
            "frames_dropped": dropped,
            "frames_processed": processed,
        }
        streams = [s for s in m.monitor if s["stream"] is not None]
        if streams:
            kbit = [s["stream_kbit_per_s"] for s in streams]
            sent = sum(s["stream"]["messages"] for s in streams)
            line += f"; stream {np.mean(kbit):.1f} kbit/s, {sent} messages sent, {m.received} received"
            figures[name].update(stream_kbit_per_s=float(np.mean(kbit)), messages_sent=sent, received=m.received)
        console.print(line)
    return figures


def depth_channel_cost(source: str, repeats: int, console: Console) -> dict:
    """Wall and thread CPU ms per frame of the depth-quality channels on every frame of ``source``: ``repeats``
    sessions' channels side by side (each its own registration fit), every frame once to each."""
    cfg = load_monitor_config().depth
    sessions = [DepthQuality(cfg) for _ in range(repeats)]
    wall, cpu, previous = [], [], None
    with open_source(parse_source_spec(source), load_camera_config(), with_depth=True) as frames:
        truth = frames.ground_truth()
        poses = truth.matrices if truth is not None else None
        for frame in frames.frames():
            intr = frame.intrinsics
            pose = poses[np.argmin(np.abs(truth.timestamps - frame.timestamp))] if poses is not None else None
            moved = np.linalg.inv(previous) @ pose if pose is not None and previous is not None else None
            previous = pose
            for session in sessions:
                start, start_cpu = time.perf_counter(), time.thread_time()
                session.frame(frame.depth, frame.gray, intr, moved)
                wall.append((time.perf_counter() - start) * 1000.0)
                cpu.append((time.thread_time() - start_cpu) * 1000.0)
    figures = {
        "depth_channels_ms_median": float(np.median(wall)),
        "depth_channels_ms_p90": float(np.percentile(wall, 90)),
        "depth_channels_cpu_ms_mean": float(np.mean(cpu)),
        "depth_channel_calls": len(wall),
    }
    console.print(
        f"depth channels: {figures['depth_channels_ms_median']:.3f} ms/frame median wall "
        f"(p90 {figures['depth_channels_ms_p90']:.3f}), {figures['depth_channels_cpu_ms_mean']:.3f} ms/frame "
        f"thread CPU, {len(wall)} calls ({repeats} per frame)"
    )
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", default=f"tum:{REPO / 'data' / 'sample'}", help="KIND:PATH (default the sample)")
    parser.add_argument("--mode", choices=[m.value for m in SlamMode], default=SlamMode.RGBD.value)
    parser.add_argument("--runs", type=int, default=3, help="runs per configuration (alternating)")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    args = parser.parse_args()
    console = Console()
    results = {name: Measurements() for name in CONFIGURATIONS}
    for run in range(args.runs):
        for name in CONFIGURATIONS:
            console.print(f"run {run + 1}/{args.runs}: {name}")
            run_once(name, args.source, SlamMode(args.mode), args.max_frames, results[name])
    figures = report(results, console)
    if SlamMode(args.mode) is SlamMode.RGBD:
        figures["depth_channels"] = depth_channel_cost(args.source, 5, console)
    console.print(f"load average {os.getloadavg()[0]:.2f} (1 min)")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
