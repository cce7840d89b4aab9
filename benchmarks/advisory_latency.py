"""Advisory latency and cadence under a real-time audio backend (a private JACK dummy server).

Runs the two advisory processes (generator, player) as in ``seesys advisory run``, publishes real Estimate messages
at 30 Hz whose level changes at random moments (so N changes at random phases of the 3 Hz cadence), then reads the
session logs and prints:

- **estimate → sound**: from the arrival at the generator of the estimate that changed N (``advisory.csv``
  ``arrival_mono``) to the DAC time of the first sample of the buffer carrying the new N (``playback.csv``
  ``dac_mono``: CLOCK_MONOTONIC in the callback + ``outputBufferDacTime − currentTime``); also from the
  publisher's send.
- **estimate → buffer at the player** (generator + hand-off) and the **margin** left before the buffer is due:
  every buffer is scheduled `schedule_latency_s` after the moment it stands for, so the sound latency is that
  constant unless the margin runs out (a late buffer starts at once and shows as a larger latency).
- **cadence jitter**: DAC-time interval between consecutive tick buffers minus 1/3 s.

Usage: ``.venv/bin/python benchmarks/advisory_latency.py [--seconds 30] [--seed 0]``
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import zmq

from advisory.config import load_advisory_config
from advisory.process import advisory_command
from advisory.sandbox import JACK_HOST_API, JackDummy, process_env
from seesys.core.messages import Estimate, encode
from seesys.core.session_layout import ADVISORY_CSV, EVENTS_CSV, PLAYBACK_CSV
from seesys.io.config import write_config_dir
from seesys.io.transport import publisher

PUBLISH_HZ = 30.0
LEVELS_M = (0.002, 0.006, 0.010, 0.020)  # N = 0, 1, 2, 3


def wait_started(session: Path, processes: tuple[str, ...], timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if (session / EVENTS_CSV).exists():
            events = pd.read_csv(session / EVENTS_CSV)
            started = {p.split("[")[0] for p in events[events.event == "started"].process}
            if set(processes) <= started:
                return
        time.sleep(0.1)
    raise SystemExit(f"{processes} did not start; see {session}")


def publish(endpoint: str, seconds: float, rng: np.random.Generator) -> np.ndarray:
    """Publish estimates at 30 Hz, holding a random level for 0.4–1.2 s at a time; returns the send times."""
    ctx = zmq.Context()
    pub = publisher(ctx, endpoint, "benchmark estimates", send_hwm=1000)
    time.sleep(0.5)  # the generator's SUB connects; what is sent before is lost, and not timed
    sent = []
    start = time.monotonic()
    level, change_at = LEVELS_M[0], 0.0
    index = 0
    while (now := time.monotonic()) - start < seconds:
        if now - start >= change_at:
            level = rng.choice([v for v in LEVELS_M if v != level])
            change_at = now - start + rng.uniform(0.4, 1.2)
        sent.append(time.monotonic())
        pub.send_multipart(encode(Estimate("bench", index, index / PUBLISH_HZ, float(level), "bench")))
        index += 1
        time.sleep(max(start + index / PUBLISH_HZ - time.monotonic(), 0.0))
    pub.close()
    ctx.term()
    return np.array(sent)


def percentiles(values_ms: np.ndarray) -> str:
    p50, p95, p99 = np.percentile(values_ms, [50, 95, 99])
    return f"n={values_ms.size} p50={p50:.1f} ms p95={p95:.1f} ms p99={p99:.1f} ms max={values_ms.max():.1f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    cfg = load_advisory_config()
    root = Path(tempfile.mkdtemp(prefix="sadvb", dir="/tmp"))
    session = root / "session"
    estimates = f"ipc://{root}/estimates"
    config = write_config_dir(
        root / "configs",
        {
            "host_api": JACK_HOST_API,
            "endpoint": f"ipc://{root}/handoff",
            "estimates_endpoint": estimates,
            "features_endpoint": f"ipc://{root}/features",
        },
    )
    procs = []
    try:
        with JackDummy(cfg.audio.sample_rate, cfg.audio.blocksize) as jack:
            env = process_env(config, jack)
            for command in (
                ["player", "--out", str(session)],
                ["generator", "--condition", "seesys", "--out", str(session)],
            ):
                procs.append(subprocess.Popen(advisory_command(*command), env=env, stderr=subprocess.DEVNULL))
            wait_started(session, ("player", "generator"))
            sent = publish(estimates, args.seconds, np.random.default_rng(args.seed))
            time.sleep(0.5)
            for proc in procs:
                proc.terminate()
            for proc in procs:
                proc.wait(10)
        generated = pd.read_csv(session / ADVISORY_CSV)
        played = pd.read_csv(session / PLAYBACK_CSV)
        events = pd.read_csv(session / EVENTS_CSV)
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
        shutil.rmtree(root, ignore_errors=True)

    joined = played.merge(generated[["buffer_id", "status"]], on="buffer_id")
    changes = joined[joined.trigger == "change"]
    arrival_to_dac = (changes.dac_mono - changes.arrival_mono).to_numpy() * 1000
    send_index = np.searchsorted(sent, changes.arrival_mono.to_numpy(), side="right") - 1
    send_to_dac = (changes.dac_mono.to_numpy() - sent[send_index]) * 1000
    ticks = played.sort_values("buffer_id")
    consecutive = (ticks.trigger == "tick") & (ticks.trigger.shift() == "tick") & (ticks.buffer_id.diff() == 1)
    deviation = (ticks.dac_mono.diff()[consecutive] - cfg.timing.cadence_s).to_numpy() * 1000
    arrival_to_player = (changes.received_mono - changes.arrival_mono).to_numpy() * 1000
    margin = (played.play_at_mono - played.received_mono).to_numpy() * 1000
    tick_rows = ticks[ticks.trigger == "tick"]
    tick_to_dac = (tick_rows.dac_mono - tick_rows.time_mono).to_numpy() * 1000
    underflows = events[events.event == "stream status"].detail.str.extract(r"^(\d+)")[0].astype(float).sum()

    print(
        f"advisory latency benchmark: {args.seconds:.0f} s of estimates at {PUBLISH_HZ:.0f} Hz, JACK dummy "
        f"{cfg.audio.sample_rate} Hz / {cfg.audio.blocksize}-frame periods, schedule_latency_s="
        f"{cfg.audio.schedule_latency_s}"
    )
    print(
        f"buffers generated {len(generated)}, played {len(played)} "
        f"({(generated.trigger == 'change').sum()} changes of N); callbacks flagged (xruns): {underflows:.0f}; "
        f"device lost: {(events.event == 'audio device lost').sum()}"
    )
    print(f"estimate arrival -> sound (DAC), changes of N: {percentiles(arrival_to_dac)}")
    print(f"estimate sent -> sound (DAC), changes of N:    {percentiles(send_to_dac)}")
    print(f"estimate arrival -> buffer at the player:      {percentiles(arrival_to_player)}")
    print(
        f"margin (play_at - receipt at the player), all: n={margin.size} min={margin.min():.1f} ms "
        f"p5={np.percentile(margin, 5):.1f} ms p50={np.median(margin):.1f} ms (a block + the output latency, "
        f"{1000 * (cfg.audio.blocksize / cfg.audio.sample_rate):.1f} ms + ~2 periods under JACK, must fit in it)"
    )
    print(f"tick -> sound (DAC), 3 Hz buffers:             {percentiles(tick_to_dac)}")
    print(
        f"cadence jitter (tick-to-tick DAC interval - 1/3 s): n={deviation.size} "
        f"std={deviation.std():.3f} ms p95|dev|={np.percentile(np.abs(deviation), 95):.3f} ms "
        f"max|dev|={np.abs(deviation).max():.3f} ms"
    )


if __name__ == "__main__":
    main()
