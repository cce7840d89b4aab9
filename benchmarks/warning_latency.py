"""Warning latency of the whole app: from the frame whose error crosses an Equation 2 threshold to the first audio
sample of the new pulse count.

Replays a recorded session (default: the embedded sample, at camera rate) through ``seesys run --local
--condition seesys --wav`` (device, estimator service with the shipped model, advisory on a private JACK dummy
server, all on private ipc endpoints), ``--runs`` times, then reads each session folder:

- **Estimate onsets.** The estimates the device logged (``estimates.csv``), in frame order; each falls in one of
  Equation 2's bands (below alpha: silence; alpha to beta: N grows with the error; beta and above: the most
  pulses). An onset is an estimate whose band differs from the previous estimate's. Its frame was captured
  ``capture_to_estimate_ms`` before the estimate arrived (ORB-SLAM3's time, the monitor, the network both ways and
  the service). The warning is the first buffer the player started after that capture whose pulse count is in the
  new band (``playback.csv``: the DAC time of its first sample), looked for within ``--horizon`` seconds (default
  1 s) of the capture: the advisory's 0.33 s moving average can smooth a one-estimate crossing away, and such
  onsets are counted as *not heard*.
  With ``--onsets`` each estimate onset is printed: its frame, the estimates before and at it, its latency and how
  many later estimates had arrived before it was heard (0: the onset's own estimate moved the moving average into
  the new band; 1 or more: the average crossed only with them, one estimate period, 167 ms at 6 Hz, each).
- **True-error onsets.** The same from the frame's true error (``seesys.core.labels``, the label the model learnt):
  a labelled frame whose band differs from the previous labelled frame's. Frame capture times come from the
  estimates' (frame time → capture time) pairs, interpolated. The true error changes from frame to frame much more
  than the estimates: many of its onsets are not heard; the figure shows how late the advisory follows the ones
  that are.

Latency = DAC time − capture time; p50/p95 over all onsets of all runs, against the target p95 ≤ 400 ms (one 1/3 s
buffer period included). CLOCK_MONOTONIC (the player's DAC times) is turned into Unix time (the device's logs) with
the offset between the two clocks measured here: every process runs on this machine.

Usage: ``.venv/bin/python benchmarks/warning_latency.py [--runs 10] [--source tum:data/sample] [--max-frames N]
[--horizon 1.0] [--keep DIR] [--onsets]``. Run it on a quiet machine: the device, the service and the advisory
share its cores.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from advisory.config import AdvisoryConfig, load_advisory_config
from estimator.service.sandbox import private_configs
from seesys.core.equation2 import max_pulses
from seesys.core.session_layout import ESTIMATES_CSV, PLAYBACK_CSV
from seesys.io.config import CONFIG_DIR_ENV
from seesys_app.summary import true_error

REPO = Path(__file__).resolve().parent.parent
TARGET_P95_MS = 400.0


def band(error_m: np.ndarray, cfg: AdvisoryConfig) -> np.ndarray:
    """Equation 2's band of each error: 0 below alpha, 1 from alpha to beta, 2 from beta."""
    eq = cfg.equation2
    return np.where(error_m < eq.alpha_m, 0, np.where(error_m < eq.beta_m, 1, 2))


def pulse_band(n: np.ndarray, cfg: AdvisoryConfig) -> np.ndarray:
    """The band a buffer's pulse count belongs to."""
    top = max_pulses(cfg.equation2, cfg.timing.buffer_s)
    return np.where(n == 0, 0, np.where(n < top, 1, 2))


def onsets(bands: np.ndarray) -> np.ndarray:
    """Index of every band change (the first of the new band)."""
    return np.flatnonzero(np.diff(bands) != 0) + 1


@dataclass(frozen=True)
class Onset:
    """One band change and when the advisory played the new band (None: not heard within the horizon)."""

    latency_ms: float | None
    # Estimate onsets only: the frame, the estimates before and at the change (m), and how many later estimates had
    # arrived by the time the new band was heard.
    frame: int | None = None
    before_m: float | None = None
    at_m: float | None = None
    later_estimates: int | None = None


def warning_latencies(
    folder: Path, cfg: AdvisoryConfig, mono_to_unix: float, horizon_s: float
) -> dict[str, list[Onset]]:
    """Estimate and true-error onsets of one session, with their latencies."""
    estimates = pd.read_csv(folder / ESTIMATES_CSV).dropna(subset=["capture_to_estimate_ms"]).sort_values("frame_index")
    playback = pd.read_csv(folder / PLAYBACK_CSV)
    heard_at = playback.dac_mono.to_numpy() + mono_to_unix
    heard_band = pulse_band(playback.played_pulses.to_numpy(), cfg)
    received = estimates.received_unix.to_numpy()
    captured = received - estimates.capture_to_estimate_ms.to_numpy() / 1000.0

    def heard(at: float, new_band: int) -> float | None:
        hits = np.flatnonzero((heard_at >= at) & (heard_at <= at + horizon_s) & (heard_band == new_band))
        return None if hits.size == 0 else float(heard_at[hits[0]])

    result: dict[str, list[Onset]] = {"estimate": [], "true error": []}
    if len(estimates) < 2:
        return result
    error = estimates.error_m.to_numpy()
    bands = band(error, cfg)
    for i in onsets(bands):
        when = heard(captured[i], int(bands[i]))
        result["estimate"].append(
            Onset(
                None if when is None else (when - captured[i]) * 1000.0,
                int(estimates.frame_index.iloc[i]),
                float(error[i - 1]),
                float(error[i]),
                None if when is None else int(np.count_nonzero((received > received[i]) & (received <= when))),
            )
        )
    truth = true_error(folder, False, folder / "configs")
    if truth is not None and len(truth):
        frame_capture = np.interp(truth.timestamp, estimates.timestamp, captured, left=np.nan, right=np.nan)
        keep = np.isfinite(frame_capture)
        at, true_bands = frame_capture[keep], band(truth.error_m.to_numpy()[keep], cfg)
        for i in onsets(true_bands):
            when = heard(at[i], int(true_bands[i]))
            result["true error"].append(Onset(None if when is None else (when - at[i]) * 1000.0))
    return result


def run_app(root: Path, k: int, source: str, max_frames: int | None) -> Path:
    """One ``seesys run`` in ``root``; its session folder."""
    config_dir, _ = private_configs(root / f"c{k}", endpoint=f"ipc://{root}/c{k}/handoff")
    out = root / f"run{k}"
    command = [
        sys.executable,
        "-m",
        "seesys",
        "run",
        "--source",
        source,
        "--local",
        "--condition",
        "seesys",
        "--wav",
        "--out",
        str(out),
    ] + (["--max-frames", str(max_frames)] if max_frames else [])
    done = subprocess.run(
        command, cwd=REPO, env={**os.environ, CONFIG_DIR_ENV: str(config_dir)}, capture_output=True, text=True
    )
    print(done.stdout.strip().splitlines()[-1] if done.stdout.strip() else done.stderr.strip())
    if done.returncode != 0:
        raise SystemExit(f"seesys run failed (status {done.returncode}):\n{done.stderr[-3000:]}")
    return out


def report(name: str, values: list[Onset]) -> str:
    heard = np.array([v.latency_ms for v in values if v.latency_ms is not None])
    if heard.size == 0:
        return f"{name:>11} onsets: {len(values)}, none heard"
    p50, p95 = np.percentile(heard, [50, 95])
    return (
        f"{name:>11} onsets: {len(values)}, heard {heard.size}; latency p50 {p50:.0f} ms, p95 {p95:.0f} ms, "
        f"max {heard.max():.0f} ms"
    )


def describe(run: int, onset: Onset) -> str:
    assert onset.before_m is not None and onset.at_m is not None
    heard = "not heard" if onset.latency_ms is None else f"heard after {onset.latency_ms:.0f} ms"
    later = "" if onset.later_estimates is None else f", {onset.later_estimates} later estimate(s) arrived by then"
    return (
        f"run {run} frame {onset.frame}: estimate {onset.before_m * 1000:.2f} -> {onset.at_m * 1000:.2f} mm, "
        f"{heard}{later}"
    )


def by_later_estimates(values: list[Onset]) -> str:
    """The heard estimate onsets grouped by how many later estimates the advisory's average waited for."""
    groups: dict[int, list[float]] = {}
    for onset in values:
        if onset.latency_ms is not None and onset.later_estimates is not None:
            groups.setdefault(onset.later_estimates, []).append(onset.latency_ms)
    parts = [f"{k}: {len(v)} onsets, p50 {np.percentile(v, 50):.0f} ms" for k, v in sorted(groups.items())]
    return "estimate onsets by later estimates needed before heard: " + ("; ".join(parts) or "none heard")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10, help="app runs (default 10)")
    parser.add_argument("--source", default="tum:data/sample", help="recording to replay (default the sample)")
    parser.add_argument("--max-frames", type=int, help="stop each run after N frames (a smoke test)")
    parser.add_argument(
        "--horizon",
        type=float,
        default=1.0,
        help="an onset not heard within this many seconds counts as not heard (default 1)",
    )
    parser.add_argument("--keep", type=Path, help="keep the session folders here")
    parser.add_argument("--onsets", action="store_true", help="print every estimate onset and why it took its time")
    args = parser.parse_args()
    cfg = load_advisory_config()
    root = Path(tempfile.mkdtemp(prefix="swl", dir="/tmp"))  # ipc paths must stay short
    mono_to_unix = time.time() - time.monotonic()
    totals: dict[str, list[Onset]] = {"estimate": [], "true error": []}
    try:
        for k in range(args.runs):
            folder = run_app(root, k, args.source, args.max_frames)
            for name, values in warning_latencies(folder, cfg, mono_to_unix, args.horizon).items():
                totals[name] += values
                if args.onsets and name == "estimate":
                    for onset in values:
                        print(describe(k, onset))
        print(
            f"Equation 2 thresholds alpha {cfg.equation2.alpha_m * 1000:g} mm, beta "
            f"{cfg.equation2.beta_m * 1000:g} mm; {args.runs} run(s) of {args.source}"
        )
        for name, values in totals.items():
            print(report(name, values))
        print(by_later_estimates(totals["estimate"]))
        heard = [v.latency_ms for v in totals["estimate"] if v.latency_ms is not None]
        if heard:
            p95 = float(np.percentile(heard, 95))
            print(
                f"target p95 <= {TARGET_P95_MS:.0f} ms from the estimate's frame: "
                f"{'met' if p95 <= TARGET_P95_MS else 'NOT met'} ({p95:.0f} ms)"
            )
    finally:
        if args.keep:  # the session folders only (the configs' ipc sockets cannot be copied)
            for folder in sorted(root.glob("run*")):
                shutil.copytree(folder, args.keep / folder.name, dirs_exist_ok=True)
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
