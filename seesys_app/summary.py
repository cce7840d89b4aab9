"""The end of a ``seesys run``: ``summary.json`` and a plot of the session.

``summary.json`` holds the outcome (``completed``: the source ended; ``interrupted``: Ctrl-C or SIGTERM;
``failed``: a child failed beyond restarting or could not start, with the error), the run's options, how the audio
was played, per part its restarts and exit statuses, frames and the fraction tracked, estimates and their
end-to-end latency percentiles, the advisory's buffers and pulses, the drops counted, and the files written.

The plot (:func:`plot_session`) shows over the session's time the estimated error (from the device's
``estimates.csv``), the true error when the source had a ground truth (``seesys.core.labels``: the same label the
model was trained on), Equation 2's thresholds alpha and beta, and below it the pulses of every buffer the advisory
played. The advisory logs wall-clock times and the estimates frame times: the buffers played while estimates came
are placed on the frame time line by interpolating between the estimates' arrival times and their frames' times.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core.equation2 import Equation2Config
from seesys.core.errors import SeesysError
from seesys.core.session_layout import ADVISORY_CSV, ESTIMATES_CSV, FRAMES_CSV, GROUND_TRUTH, PLAYBACK_CSV
from seesys.core.tracking_state import TrackingState
from seesys.io.logfiles import read_csv_log, write_json_atomically
from seesys_app.config import OutputConfig
from seesys_app.records import RunRecord

PERCENTILES = (50, 95, 99)
# The names frames.csv gives the states in which a frame has a pose SLAM considers good (OK and OK_KLT).
TRACKED_STATES = tuple(state.name for state in TrackingState if state.tracked)


def _table(path: Path) -> pd.DataFrame:
    """A session log as a table (empty when it is missing or empty)."""
    try:
        return read_csv_log(path)
    except (OSError, pd.errors.EmptyDataError):
        return pd.DataFrame()


def _percentiles(values: pd.Series) -> dict[str, float | None]:
    values = pd.to_numeric(values, errors="coerce").dropna()
    if values.empty:
        return {f"p{p}": None for p in PERCENTILES}
    return {f"p{p}": round(float(np.percentile(values, p)), 3) for p in PERCENTILES}


def session_figures(folder: Path) -> dict:
    """Frames, estimates, latency and advisory figures of a session folder's logs."""
    frames, estimates = _table(folder / FRAMES_CSV), _table(folder / ESTIMATES_CSV)
    advisory, playback = _table(folder / ADVISORY_CSV), _table(folder / PLAYBACK_CSV)
    tracked = float(frames["state"].isin(TRACKED_STATES).mean()) if len(frames) else None
    figures: dict[str, object] = {
        "frames": len(frames),
        "tracked_fraction": tracked,
        "estimates": len(estimates),
        "end_to_end_ms": _percentiles(estimates.get("end_to_end_ms", pd.Series(dtype=float))),
        "estimate_error_m": (
            {
                "min": float(estimates.error_m.min()),
                "median": float(estimates.error_m.median()),
                "max": float(estimates.error_m.max()),
            }
            if len(estimates)
            else None
        ),
        "buffers": len(advisory),
        "buffers_played": len(playback),
    }
    if len(advisory):
        counts = advisory.played_pulses.value_counts().sort_index()
        figures["buffers_by_pulses"] = {str(int(n)): int(c) for n, c in counts.items()}
    return figures


def true_error(folder: Path, monocular: bool, config_dir: Path | None) -> pd.DataFrame | None:
    """The true per-frame error of a session with a ground truth (labelled frames only), or None."""
    from seesys.io.core_settings import load_label_config
    from seesys.io.session_labels import label_session

    if not (folder / GROUND_TRUTH).is_file():
        return None
    labels = label_session(folder, monocular, load_label_config(config_dir)).to_frame()
    return labels[labels.status == "labelled"]


def broken_at_gaps(t: np.ndarray, values: np.ndarray, gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``t`` and ``values`` (in time order) with a NaN point inserted where consecutive times are more than
    ``gap_s`` apart, so that a line plot breaks there instead of bridging a time without data."""
    t, values = np.asarray(t, dtype=float), np.asarray(values, dtype=float)
    after = np.flatnonzero(np.diff(t) > gap_s) + 1
    return np.insert(t, after, np.nan), np.insert(values, after, np.nan)


def plot_session(
    folder: Path,
    equation2: Equation2Config,
    out: Path,
    monocular: bool = False,
    config_dir: Path | None = None,
    gap_s: float = math.inf,
) -> Path:
    """Write the session plot (see the module docstring) to ``out``, the estimate line broken where estimates are
    more than ``gap_s`` apart (an estimator outage); SeesysError when there is nothing to plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    estimates, buffers = _table(folder / ESTIMATES_CSV), _table(folder / ADVISORY_CSV)
    frames = _table(folder / FRAMES_CSV)
    if frames.empty:
        raise SeesysError(f"{folder}: no frames logged, nothing to plot")
    t0 = float(frames.timestamp.iloc[0])
    truth = true_error(folder, monocular, config_dir)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, height_ratios=(3, 1))
    if truth is not None and len(truth):
        top.plot(truth.timestamp - t0, truth.error_m * 100, color="0.4", lw=1, label="true error")
    if len(estimates):
        t, error_m = broken_at_gaps(estimates.timestamp - t0, estimates.error_m, gap_s)
        top.plot(t, error_m * 100, "o-", ms=3, color="tab:blue", label="estimated error")
    eq = equation2
    for value, name in ((eq.alpha_m, "α"), (eq.beta_m, "β")):
        top.axhline(value * 100, color="tab:red", ls="--", lw=1)
        top.annotate(
            f"Equation 2 {name} = {value * 100:g} cm",
            (0, value * 100),
            textcoords="offset points",
            xytext=(2, 2),
            color="tab:red",
            fontsize=8,
        )
    top.set_ylabel("pose error (cm)")
    top.legend(loc="upper right")
    top.set_title(f"{folder.name}: estimated vs true error, and the pulses played")
    if len(buffers) and len(estimates):
        received = estimates.sort_values("received_unix")
        inside = buffers[buffers.wall_time.between(received.received_unix.iloc[0], received.received_unix.iloc[-1])]
        at = np.interp(inside.wall_time, received.received_unix, received.timestamp)
        bottom.step(at - t0, inside.played_pulses, where="post", color="tab:green")
    bottom.set_xlim(0, float(frames.timestamp.iloc[-1]) - t0)
    bottom.set_ylabel("pulses / buffer")
    bottom.set_xlabel("time since the first frame (s)")
    bottom.set_yticks(range(0, 4))
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def write_summary(
    run: RunRecord,
    out: OutputConfig,
    *,
    status: str,
    error: str | None,
    started: str,
    ended: str,
    exits: dict[str, int | None],
) -> dict:
    """Write ``summary.json`` and the plot of a finished run; returns the summary. A plot that cannot be made is
    noted in the summary, never fatal: the logs are what matters."""
    folder = run.folder
    summary = {
        "status": status,
        "error": error,
        "started": started,
        "ended": ended,
        "source": run.source,
        "mode": run.mode,
        "paced": run.paced,
        "condition": run.condition,
        "estimator": run.estimator,
        "audio": run.audio,
        "parts": {
            name: {"restarts": part.restarts, "exits": list(part.exits), "final_exit": exits.get(name)}
            for name, part in run.parts.items()
        },
        **session_figures(folder),
    }
    summary["information"] = {
        "seconds_without": round(run.seconds_without_information, 2),
        "by_reason": {reason: round(seconds, 2) for reason, seconds in run.without_information_by_reason.items()},
    }
    if run.drops is not None:
        summary["drops"] = {**asdict(run.drops), "estimator": run.estimator_dropped}
    files = {"events": out.events, "logs": "logs"}
    if (folder / out.wav).exists():
        files["wav"] = out.wav
    try:
        plot_session(folder, run.equation2, folder / out.plot, run.mode == "mono", run.config_dir, run.stale_after_s)
        files["plot"] = out.plot
    except (SeesysError, ValueError, KeyError) as e:
        summary["plot_error"] = str(e)
    summary["files"] = files
    summary = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in summary.items()}
    write_json_atomically(folder / out.summary, summary)
    return summary
