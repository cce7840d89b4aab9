"""Estimator service latency and throughput: one device's path against the model alone, then many simulated devices
on 1 and 2 worker processes.

First, one device's latency beside the model's own cost, in one run: the served model alone (ONNX Runtime, batch 1,
one intra-op thread, as a worker runs it) on the session's windows, back to back and paced at one device's window
rate; then one simulated device for ``--latency-seconds`` against each of two fresh services in turn, one with one
worker process (``worker process``) and one whose broker runs the model itself (``--workers 0``: ``in the broker``),
its latency at the device beside the model's, and where each millisecond goes: each service's stage breakdown
(:mod:`estimator.service.stages`, p50 and p99 of each stage from ``seesys estimator status``) and the transit
(device → broker and broker → device: the device's latency less the server's). Beside them, the floor of any path
through a broker and a worker process: a bare ZeroMQ round trip between two processes (DEALER ⇄ ROUTER over ipc, a
200-byte message, paced as one device's windows), of which the path makes two (device ⇄ broker, broker ⇄ worker),
and the same round trip with both processes on one core (what crossing between cores adds to it on this machine);
and the floor of a path with one crossing: one process that does in its loop what the broker and the worker do on
the path (decode the frame, add it to its device's window, prepare and run the model, encode the estimate and publish
it; the service's code for each), with no broker, no worker, no checks or counters, timed the same way at the device
(the least a service of any layout could reach on this machine with these stages).

Then the throughput rows. Each simulated device replays a logged session's feature stream (``rts.csv`` +
``psd/``) at 30 Hz on its own connection to ``seesys estimator serve`` (a subprocess with a private configuration:
ipc:// endpoints, the configured windows, stale limit and batching). The devices' window ends are spread evenly
over one estimate period, as independent devices' are (``--bunched``: all in the same frame period, one burst per
estimate period; see :mod:`estimator.service.simulate`). Per row it prints, over ``--seconds`` of replay:

- **latency** p50/p90/p99: feature message of a window's last frame sent → its estimate received, at the device
  (transmit + inference; the device's own preprocessing is not part of a replay);
- **estimates/s** received, against the **expected** rate: every window the replay lets form (devices × 30 /
  end_stride, less each device's first second, which no window covers yet);
- **drops**: windows dropped as stale, frames dropped at a full worker queue, frames lost in transit (the broker's
  counters, this row only), and estimates that never came;
- **CPU**: cores used by the service (broker and workers) during the row, from their CPU times, and of them by
  the broker.

Then, per worker count, the largest number of devices served with no drop at the full rate. The first run
records a session on the embedded sample (`seesys monitor run`, about a minute) unless ``--session`` is given,
and exports the untrained model of the configured size unless the configured one exists or ``--model`` is given.

Usage: ``.venv/bin/python benchmarks/estimator_service.py [--devices 1,16,40,64,80,96] [--workers 1,2]
[--seconds 20] [--latency-seconds 30] [--bunched]`` (``--devices ''`` skips the throughput rows)
(run it on a quiet machine: the figures are only as good as the CPU left to the service).
"""

from __future__ import annotations

import argparse
import gc
import multiprocessing
import os
import platform
import subprocess
import sys
import tempfile
import time
from multiprocessing.synchronize import Event
from pathlib import Path

import numpy as np
import psutil
import zmq
from pacing import paced

from estimator.service.config import load_service_config
from estimator.service.device_windows import DeviceWindows
from estimator.service.model import ServedModel
from estimator.service.sandbox import private_configs, start_service, wait_ready
from estimator.service.simulate import DeviceFleet
from estimator.service.stages import STAGES
from estimator.service.status import query_status
from seesys.core import messages
from seesys.core.messages import Estimate, FeatureFrame
from seesys.core.windows import assemble_windows
from seesys.io.core_settings import load_window_config
from seesys.io.resources import resolve
from seesys.io.rts_log import read_feature_frames

RATE_HZ = 30.0
START_TIMEOUT_S = 300
WARMUP = 20


def _ints(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v.strip()]


def record_session(folder: Path) -> Path:
    out = folder / "session"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "monitor",
            "run",
            "--source",
            f"tum:{resolve('data/sample')}",
            "--mode",
            "rgbd",
            "--pace",
            "--out",
            str(out),
        ],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return out


def model_file(folder: Path, given: Path | None) -> Path:
    if given is not None:
        return given
    configured = resolve(load_service_config().model)
    if configured.is_file():
        return configured
    path = folder / "deepsee-untrained.onnx"
    subprocess.run(
        [sys.executable, "-m", "seesys", "estimator", "untrained-model", "--out", str(path)],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return path


def replay_inputs(folder: Path, session: Path | None, model: Path | None) -> tuple[Path, list[FeatureFrame], Path]:
    """The session to replay (a recording of the sample made in ``folder`` when none is given), its feature frames,
    and the model to serve (:func:`model_file`)."""
    session = session or record_session(folder)
    return session, list(read_feature_frames(session, "replay")), model_file(folder, model)


def service_cpu_s(process: psutil.Process, children: bool = True) -> float:
    """CPU seconds of ``process`` (the broker) and, with ``children``, of its workers."""
    total = 0.0
    for p in [process, *(process.children(recursive=True) if children else [])]:
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


def run_row(
    endpoints: dict, process: psutil.Process, frames, devices: int, seconds: float, row: int, bunched: bool
) -> dict:
    windows = load_window_config()
    fleet = DeviceFleet(endpoints["ingest"], endpoints["estimates"], [f"bench-{row}-{k}" for k in range(devices)])
    time.sleep(1.0)  # connections and subscriptions settle; frames sent before would be lost, and counted missing
    try:
        before_status, before_cpu, start = (
            query_status(endpoints["status"], 5000),
            service_cpu_s(process),
            time.perf_counter(),
        )
        before_broker = service_cpu_s(process, children=False)
        result = fleet.replay(frames, seconds, RATE_HZ, windows, bunched=bunched)
        wall = time.perf_counter() - start
        cpu = service_cpu_s(process) - before_cpu
        broker_cpu = service_cpu_s(process, children=False) - before_broker
        after_status = query_status(endpoints["status"], 5000)
    finally:
        fleet.close()
    first, last = drops(before_status), drops(after_status)
    lost = {k: last[k] - first[k] for k in first}
    # Windows that can form: those whose history the replay covers (the first ones of each device cannot).
    expected = devices * len(
        [k for k in range(int(seconds * RATE_HZ)) if k >= windows.history and windows.is_psd_frame(k)]
    )
    p50, p90, p99 = result.percentiles()
    return {
        "devices": devices,
        "p50": p50,
        "p90": p90,
        "p99": p99,
        "estimates_per_s": result.estimates_per_s,
        "expected_per_s": expected / seconds,
        "missing": max(0, expected - len(result.estimates)),
        **lost,
        "cores": cpu / wall,
        "broker": broker_cpu / wall,
    }


def paced_runs(runs: int) -> int:
    """How many paced runs go with ``runs`` back-to-back ones (a fifth, at least 20)."""
    return max(20, int(runs * 0.2))


def model_alone(model_path: Path, frames, runs: int, period_s: float) -> dict[str, np.ndarray]:
    """Seconds per ONNX Runtime run of the served model at batch 1 on the session's windows (inputs prepared
    beforehand, as the ``inference`` stage times it), back to back and one every ``period_s`` (one device's
    window rate: the idle core's caches and clock make a lone run slower)."""
    config, windows = load_service_config(), load_window_config()
    model = ServedModel.load(model_path, windows, threads=1, providers=config.providers)
    inputs = [model.prepare([w]) for w in assemble_windows(frames, windows)]
    for k in range(WARMUP):
        model.run(inputs[k % len(inputs)])
    back_to_back = np.empty(runs)
    for k in range(runs):
        start = time.perf_counter()
        model.run(inputs[k % len(inputs)])
        back_to_back[k] = time.perf_counter() - start
    once_per_period = np.empty(paced_runs(runs))
    for k in paced(len(once_per_period), period_s):
        start = time.perf_counter()
        model.run(inputs[k % len(inputs)])
        once_per_period[k] = time.perf_counter() - start
    return {"back_to_back": back_to_back * 1000.0, "paced": once_per_period * 1000.0}


def _echo(endpoint: str, cpu: int | None) -> None:
    """The far end of :func:`round_trip_ms`: sends every message back until an empty one (on core ``cpu`` alone
    where one is given)."""
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    with zmq.Context() as context, context.socket(zmq.ROUTER) as router:
        router.bind(endpoint)
        while True:
            peer, body = router.recv_multipart()
            router.send_multipart([peer, body])
            if not body:
                return


def round_trip_ms(folder: Path, runs: int, period_s: float, cpu: int | None = None) -> np.ndarray:
    """Milliseconds per bare round trip between this process and another (DEALER ⇄ ROUTER over ipc, 200 bytes),
    one every ``period_s``: the least any crossing to another process and back costs at one device's pace. With
    ``cpu``, both processes run on that core alone: a wake-up on the same core instead of a signal to another (on a
    VM, where that signal leaves the guest, the difference is the cost of crossing cores)."""
    endpoint = f"ipc://{folder.resolve()}/echo"
    echo = multiprocessing.get_context("spawn").Process(target=_echo, args=(endpoint, cpu))
    echo.start()
    cores = os.sched_getaffinity(0)
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    message, times = b"\0" * 200, np.empty(runs)
    try:
        with zmq.Context() as context, context.socket(zmq.DEALER) as dealer:
            dealer.connect(endpoint)
            for _ in range(WARMUP):
                dealer.send(message)
                dealer.recv()
            for k in paced(runs, period_s):
                start = time.perf_counter()
                dealer.send(message)
                dealer.recv()
                times[k] = time.perf_counter() - start
            dealer.send(b"")
            dealer.recv()
    finally:
        os.sched_setaffinity(0, cores)
        echo.join(10)
        if echo.is_alive():
            echo.kill()
    return times * 1000.0


def _one_process_service(ingest: str, estimates: str, model_path: Path, ready: Event) -> None:
    """The far end of :func:`one_process_ms`: each frame decoded, added to its window and, where one ends, the model
    run and the estimate published, in this one loop (ended by the parent's terminate)."""
    windows, config = load_window_config(), load_service_config()
    model = ServedModel.load(model_path, windows, threads=1, providers=config.providers)
    device_windows = DeviceWindows(model, windows)
    context = zmq.Context()
    ingest_socket, estimates_socket = context.socket(zmq.SUB), context.socket(zmq.PUB)
    ingest_socket.subscribe(b"")
    ingest_socket.bind(ingest)
    estimates_socket.bind(estimates)
    gc.freeze()  # as the broker and the worker do
    ready.set()
    while True:
        frame = messages.decode(ingest_socket.recv_multipart(), psd=model.reads_psd)
        if not isinstance(frame, FeatureFrame):
            continue
        window = device_windows.add(frame).window
        if window is None:
            continue
        result = model.run(model.prepare([window]))
        estimate = Estimate(
            window.device_id,
            window.frame_index,
            window.timestamp,
            float(result.errors_m[0]),
            model.version,
            0.0,
            frame.stream_session,
            result.head(0),
            frame.translation_covariance,
        )
        estimates_socket.send_multipart(messages.encode(estimate))


def one_process_ms(folder: Path, model: Path, frames, seconds: float) -> np.ndarray:
    """One simulated device's latencies (ms) against :func:`_one_process_service`: the floor of a path with one
    crossing between processes and the service's stages on it."""
    spawn = multiprocessing.get_context("spawn")
    ingest, estimates = f"ipc://{folder.resolve()}/floor-in", f"ipc://{folder.resolve()}/floor-out"
    ready = spawn.Event()
    server = spawn.Process(target=_one_process_service, args=(ingest, estimates, model, ready))
    server.start()
    try:
        if not ready.wait(START_TIMEOUT_S):
            raise RuntimeError("the one-process service did not load its model")
        fleet = DeviceFleet(ingest, estimates, ["floor-0"])
        time.sleep(1.0)  # connections and subscriptions settle
        try:
            result = fleet.replay(frames, seconds, RATE_HZ, load_window_config())
        finally:
            fleet.close()
    finally:
        server.terminate()
        server.join(10)
    return np.asarray(result.latency_ms, dtype=float)


def decode_cpu_us(frames) -> tuple[float, float, float]:
    """CPU µs to decode one of the session's feature messages with a PSD, one with its PSD read past (what the
    broker does for a model that reads none) and one without, as the broker does for every frame (its share of the
    ``ingest`` stage; the mean of a few passes)."""
    encoded = [(messages.encode(f), f.psd is not None) for f in frames]
    costs = []
    for with_psd, inflate in ((True, True), (True, False), (False, True)):
        chosen = [parts for parts, has in encoded if has == with_psd] * 5
        start = time.process_time()
        for parts in chosen:
            messages.decode(parts, psd=inflate)
        costs.append((time.process_time() - start) / max(1, len(chosen)) * 1e6)
    return costs[0], costs[1], costs[2]


def _p(values, q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


def _row(name: str, p50: float, p99: float, n: int | None = None, sign: str = "") -> None:
    print(f"{name:<60}{p50:>{sign}8.2f}{p99:>{sign}8.2f}" + (f"{n:>6}" if n is not None else ""))


def print_latency(
    model: dict[str, np.ndarray],
    paths: dict[str, dict],
    period_s: float,
    round_trip: np.ndarray,
    round_trip_one_core: np.ndarray,
    one_process: np.ndarray,
) -> None:
    """The one-device table: the model alone and each service path (``paths``: by layout, as :func:`latency_run`
    gives it) side by side, each path's excess over the model, the floors (two round trips between processes, and
    one with both processes on one core; one process doing the path's stages), and each path's breakdown."""
    print(
        "\none device, window's last frame sent → estimate received, against the model alone (ONNX Runtime, "
        "batch 1, 1 thread); ms"
    )
    print(f"{'':<60}{'p50':>8}{'p99':>8}{'n':>6}")
    alone = [
        ("back to back", model["back_to_back"]),
        (f"one run every {period_s * 1000:.0f} ms", model["paced"]),
    ]
    latencies = {layout: np.asarray(row["latencies"], dtype=float) for layout, row in paths.items()}
    measured = [*latencies.items(), ("one process, the path's stages only", one_process)]
    labelled = [
        *((f"model alone, {base}", values) for base, values in alone),
        *((f"service path, {layout}", values) for layout, values in latencies.items()),
        measured[-1],
    ]
    for name, values in labelled:
        _row(name, _p(values, 50), _p(values, 99), len(values))
    for name, values in measured:
        for base, reference in alone:
            _row(f"{name} − {base}", _p(values, 50) - _p(reference, 50), _p(values, 99) - _p(reference, 99), sign="+")
    _row("bare round trip between two processes", _p(round_trip, 50), _p(round_trip, 99), len(round_trip))
    _row("two of them (a path through a worker makes two)", 2 * _p(round_trip, 50), 2 * _p(round_trip, 99))
    _row(
        "bare round trip, both processes on one core",
        _p(round_trip_one_core, 50),
        _p(round_trip_one_core, 99),
        len(round_trip_one_core),
    )
    timed = {layout: row["status"]["stages_ms"] for layout, row in paths.items() if row["status"]["stages_ms"]}
    if not timed:
        print("no stage times (no estimate reached the broker)")
        return
    print("\nwhere the time goes (each stage's own p50 and p99; p50s of parts need not add up to the total's)")
    print(f"{'':<60}" + "".join(f"{layout[:16]:>16}" for layout in timed))
    print(f"{'stage':<60}" + f"{'p50':>8}{'p99':>8}" * len(timed))
    transit = [
        f"{_p(latencies[layout], q) - stages['server'][f'p{q}']:>8.2f}"
        for layout, stages in timed.items()
        for q in (50, 99)
    ]
    print(f"{'transit, device ⇄ broker (path − server)':<60}" + "".join(transit))
    for stage in STAGES:
        print(f"{stage:<60}" + "".join(f"{t[stage]['p50']:>8.2f}{t[stage]['p99']:>8.2f}" for t in timed.values()))


def latency_run(folder: Path, model: Path, frames, seconds: float, workers: int) -> dict:
    """One simulated device against a fresh service with ``workers`` worker processes (0: the broker runs the
    model): its latencies and the service's status."""
    config_dir, endpoints = private_configs(folder / f"latency-{workers}", connect_device_stream=False)
    log = folder / f"serve-latency-{workers}.log"
    serve = start_service(config_dir, model, "--workers", str(workers), log=log)
    try:
        wait_ready(serve, endpoints["status"], START_TIMEOUT_S, log)
        windows = load_window_config()
        fleet = DeviceFleet(endpoints["ingest"], endpoints["estimates"], ["latency-0"])
        time.sleep(1.0)  # connections and subscriptions settle
        try:
            result = fleet.replay(frames, seconds, RATE_HZ, windows)
            status = query_status(endpoints["status"], 5000)
        finally:
            fleet.close()
    finally:
        serve.terminate()
        serve.wait(60)
    return {"latencies": result.latency_ms, "status": status}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--devices", type=_ints, default=[1, 16, 40, 64, 80, 96])
    parser.add_argument("--workers", type=_ints, default=[1, 2])
    parser.add_argument("--seconds", type=float, default=20.0, help="replay per row (default 20)")
    parser.add_argument(
        "--latency-seconds",
        type=float,
        default=30.0,
        help="one device's replay for the latency table (default 30; 0 skips it)",
    )
    parser.add_argument(
        "--model-runs",
        type=int,
        default=600,
        help="back-to-back runs of the model alone (a fifth as many paced; default 600)",
    )
    parser.add_argument("--session", type=Path, help="session folder to replay (default: record the sample)")
    parser.add_argument("--model", type=Path, help="ONNX model (default: configured, else an untrained stand-in)")
    parser.add_argument(
        "--bunched",
        action="store_true",
        help="all devices end their windows in the same frame period (default: spread evenly over "
        "one estimate period, as independent devices are)",
    )
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="svcb") as tmp:
        folder = Path(tmp)
        session, frames, model = replay_inputs(folder, args.session, args.model)
        windows = load_window_config()
        print(
            f"estimator service benchmark: {platform.node()}, {os.cpu_count()} CPUs, model {model.name}, session "
            f"{session} ({len(frames)} frames), {RATE_HZ:g} Hz, end_stride {windows.end_stride}, "
            f"{'bunched' if args.bunched else 'spread'} phases, "
            f"{args.seconds:g} s per row; load average before: {os.getloadavg()[0]:.2f}"
        )
        if args.latency_seconds > 0:
            period_s = windows.end_stride / RATE_HZ
            alone = model_alone(model, frames, args.model_runs, period_s)
            round_trip = round_trip_ms(folder, paced_runs(args.model_runs), period_s)
            one_core = round_trip_ms(folder, paced_runs(args.model_runs), period_s, min(os.sched_getaffinity(0)))
            paths = {
                layout: latency_run(folder, model, frames, args.latency_seconds, workers)
                for layout, workers in (("worker process", 1), ("in the broker", 0))
            }
            one_process = one_process_ms(folder, model, frames, args.latency_seconds)
            print_latency(alone, paths, period_s, round_trip, one_core, one_process)
            with_psd, read_past, without = decode_cpu_us(frames)
            print(
                f"decoding one feature message (the broker, every frame; CPU): {with_psd:.0f} µs with a PSD, "
                f"{read_past:.0f} µs with its PSD read past (a model that reads none), {without:.0f} µs without; "
                f"this model: {'reads' if ServedModel.load(model, windows).reads_psd else 'reads no'} PSD"
            )
        if not args.devices:
            print(f"load average after: {os.getloadavg()[0]:.2f}")
            return
        print()
        header = (
            f"{'workers':>7}{'devices':>8}{'p50 ms':>8}{'p90 ms':>8}{'p99 ms':>8}{'est/s':>8}{'expected':>9}"
            f"{'missing':>8}{'stale':>7}{'q-full':>7}{'lost':>6}{'cores':>7}{'broker':>7}"
        )
        print(header)
        best: dict[int, int] = {}
        most: dict[int, float] = {}
        for workers in args.workers:
            config_dir, endpoints = private_configs(folder / f"w{workers}", connect_device_stream=False)
            log = folder / f"serve-{workers}.log"
            serve = start_service(config_dir, model, "--workers", str(workers), log=log)
            try:
                wait_ready(serve, endpoints["status"], START_TIMEOUT_S, log)
                for row, devices in enumerate(args.devices):
                    r = run_row(endpoints, psutil.Process(serve.pid), frames, devices, args.seconds, row, args.bunched)
                    print(
                        f"{workers:>7}{devices:>8}{r['p50']:>8.1f}{r['p90']:>8.1f}{r['p99']:>8.1f}"
                        f"{r['estimates_per_s']:>8.1f}{r['expected_per_s']:>9.1f}{r['missing']:>8}{r['stale']:>7}"
                        f"{r['queue_full']:>7}{r['lost']:>6}{r['cores']:>7.2f}{r['broker']:>7.2f}",
                        flush=True,
                    )
                    if r["stale"] + r["queue_full"] + r["lost"] + r["missing"] == 0:
                        best[workers] = max(best.get(workers, 0), devices)
                    most[workers] = max(most.get(workers, 0.0), r["estimates_per_s"])
            finally:
                serve.terminate()
                serve.wait(60)
        for workers in args.workers:
            served = best.get(workers, 0)
            print(
                f"{workers} worker(s): at most {served} device(s) served with no drop "
                f"({served * RATE_HZ / windows.end_stride:.0f} estimates/s); most delivered in a row "
                f"{most.get(workers, 0.0):.1f} estimates/s"
            )
        print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
