"""A participant's recorded attempts, their status, and the per-participant metrics of a whole study.

Every ``seesys study run`` writes one attempt folder (``attempt-<n>``, never reused) holding the device session
(``frames.csv``, ``trajectory.tum``, ``session.json``, ...), ``groundtruth.tum``, the study's logs and
``run.json`` (participant, phase, condition, status, start and end). An attempt whose ``run.json`` still says
``running`` after its process is gone was killed: it is ``incomplete`` and its data count like any other. A
restart marks the earlier attempts of the phase ``superseded``: they stay on disk but leave the metrics. A phase is
done when an attempt ``completed`` (the source ended) or was ``stopped`` (the operator ended the task); one that was
``interrupted`` (Ctrl-C) is not. A run that failed before its device recorded a frame is no attempt: its folder is
renamed ``failed-start-<UTC time>`` (kept for its logs, never numbered).

A participant's metrics pool the non-superseded attempts of the analysed phase (``study.metrics.combine``), each
over its task only: frames logged after the operator ended the task (``run.json`` ``task_end``) are left out.
"""

from __future__ import annotations

import json
import math
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core.session_layout import ADVISORY_CSV
from seesys.core.trajectory import TrajectoryError
from seesys.io.logfiles import read_csv_log, write_json_atomically
from seesys.io.trajectory_files import read_tum
from study.advice import AdviceOutcome, advice_outcome, path_speed
from study.config import MetricsConfig
from study.estimates import wall_to_camera_offset
from study.metrics import RpeResult, TrackingMetrics, combine, measure, read_frame_log
from study.protocol import Protocol, read_protocol

RUN_JSON = "run.json"
EVENTS_CSV = "events.csv"
EVENTS_HEADER = "time,kind,detail"
ATTEMPT = re.compile(r"attempt-(\d+)$")
DONE, INCOMPLETE, PENDING = "done", "incomplete", "pending"
# An attempt with one of these statuses did the phase: the source ended, or the operator ended the task (``q``).
DONE_STATUSES = ("completed", "stopped")
#: ``run.json``'s key for the advisory's start on the session's clock (a simulated session records it).
ADVICE_START = "advice_start"
FAILED_START = "failed-start-"


def attempt_folders(phase_folder: Path) -> list[Path]:
    """The attempt folders of a phase, in order."""
    return [p for _, p in _numbered_attempts(phase_folder)]


def _numbered_attempts(phase_folder: Path) -> list[tuple[int, Path]]:
    """The attempt folders of a phase with their numbers, in order."""
    if not phase_folder.is_dir():
        return []
    return sorted((int(m.group(1)), p) for p in phase_folder.iterdir() if p.is_dir() and (m := ATTEMPT.match(p.name)))


def next_attempt_folder(phase_folder: Path) -> Path:
    """A new attempt folder (created), numbered after every existing one."""
    existing = _numbered_attempts(phase_folder)
    number = existing[-1][0] + 1 if existing else 1
    folder = phase_folder / f"attempt-{number}"
    folder.mkdir(parents=True)
    return folder


def supersede_attempts(phase_folder: Path) -> None:
    """Mark every attempt of the phase ``superseded``: kept on disk, left out of the metrics (a restart)."""
    for attempt in attempt_folders(phase_folder):
        run = read_run(attempt)
        run["superseded"] = True
        write_json_atomically(attempt / RUN_JSON, run)


def set_aside_failed_start(attempt: Path) -> Path:
    """Rename the folder of a run that failed before its device recorded anything to ``failed-start-<UTC time>``:
    kept for its logs, and neither an attempt nor a number of one."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    target = attempt.with_name(FAILED_START + stamp)
    n = 1
    while target.exists():
        n += 1
        target = attempt.with_name(f"{FAILED_START}{stamp}-{n}")
    attempt.rename(target)
    return target


def _alive(pid: object) -> bool:
    """Whether the process ``pid`` of a ``run.json`` runs; a value that is no process id (a damaged file) is none."""
    if not isinstance(pid, (int, float, str)):
        return False
    try:
        os.kill(int(pid), 0)
    except (ProcessLookupError, ValueError):
        return False
    except PermissionError:
        return True
    return True


def read_run(attempt: Path) -> dict:
    """``run.json`` of an attempt, with ``status`` ``incomplete`` when its process died while running."""
    try:
        run = json.loads((attempt / RUN_JSON).read_text())
    except (OSError, ValueError):
        return {"status": INCOMPLETE}
    if run.get("status") == "running" and not _alive(run.get("pid")):
        run["status"] = INCOMPLETE
    return run


def used_attempts(phase_folder: Path) -> list[Path]:
    return [a for a in attempt_folders(phase_folder) if not read_run(a).get("superseded")]


def done_attempts(phase_folder: Path) -> list[Path]:
    """The used attempts of a phase folder that finished (:data:`DONE_STATUSES`)."""
    return [a for a in used_attempts(phase_folder) if read_run(a).get("status") in DONE_STATUSES]


def advice_start(attempt: Path) -> float | None:
    """Where the attempt's advisory started on the session's clock (``run.json``'s :data:`ADVICE_START`, which a
    simulated session records), or None where it is not recorded."""
    value = read_run(attempt).get(ADVICE_START)
    return None if value is None else float(value)


def phase_status(phase_folder: Path) -> str:
    runs = [read_run(a) for a in used_attempts(phase_folder)]
    if any(r.get("status") in DONE_STATUSES for r in runs):
        return DONE
    return INCOMPLETE if runs else PENDING


def read_events(attempt: Path) -> pd.DataFrame:
    """The operator's events (``time,kind,detail``); a line cut short by a crash is dropped."""
    path = attempt / EVENTS_CSV
    if not path.exists():
        return pd.DataFrame({"time": [], "kind": [], "detail": []})
    return read_csv_log(path, dtype={"kind": str, "detail": str}).dropna(subset=["time", "kind"])


def time_on_task(events: pd.DataFrame) -> float | None:
    """From the ``initialised`` event to the last ``object`` event, when both were marked."""
    start = events.loc[events.kind == "initialised", "time"]
    objects = events.loc[events.kind == "object", "time"]
    if start.empty or objects.empty or objects.max() <= start.min():
        return None
    return float(objects.max() - start.min())


def task_end_s(attempt: Path) -> float | None:
    """The timestamp of the last frame of the task when the operator ended it (``run.json`` ``task_end``; -inf when
    no frame was logged by then), None when the task ran to the device's end."""
    end = read_run(attempt).get("task_end")
    if not isinstance(end, dict):
        return None
    timestamp = end.get("timestamp")
    return -math.inf if timestamp is None else float(timestamp)


@dataclass(frozen=True)
class AttemptMetrics:
    folder: Path
    rpe: RpeResult
    monocular: bool


def _monocular(attempt: Path) -> bool:
    try:
        return json.loads((attempt / "session.json").read_text()).get("mode") == "mono"
    except (OSError, ValueError):
        return False


def _read_poses(path: Path):
    try:
        return read_tum(path)
    except TrajectoryError:
        return None


def participant_metrics(
    attempts: list[Path], cfg: MetricsConfig
) -> tuple[TrackingMetrics, list[AttemptMetrics]] | None:
    """Pooled metrics of ``attempts`` (None when none has a trajectory and a ground truth)."""
    rpes, parts, per_attempt, durations = [], [], [], []
    for attempt in attempts:
        estimate, reference = _read_poses(attempt / "trajectory.tum"), _read_poses(attempt / "groundtruth.tum")
        if estimate is None or reference is None:
            continue
        monocular = _monocular(attempt)
        frames = read_frame_log(attempt / "frames.csv") if (attempt / "frames.csv").exists() else None
        rpe, part = measure(estimate, reference, monocular, cfg, frames, task_end_s(attempt))
        marked = time_on_task(read_events(attempt))
        rpes.append(rpe)
        parts.append(part)
        durations.append(part.duration_s if marked is None else marked)
        per_attempt.append(AttemptMetrics(attempt, rpe, monocular))
    if not per_attempt:
        return None
    return combine(rpes, parts, cfg, per_attempt[0].rpe.alignment, sum(durations)), per_attempt


@dataclass(frozen=True)
class StudyData:
    """Tidy tables of a study: one row per participant (and condition), and one per RPE pair."""

    protocol: Protocol
    participants: pd.DataFrame
    pairs: pd.DataFrame
    attempts: dict[tuple[str, str], list[AttemptMetrics]]


METRIC_COLUMNS = (
    "rpe_mean_m",
    "rpe_rmse_m",
    "error_per_metre",
    "error_per_radian",
    "pairs",
    "completeness",
    "tracking_losses",
    "loss_duration_s",
    "map_resets",
    "time_on_task_s",
)
ADVICE_COLUMNS = ("mean_speed_mps", "warning_share", "buffers", "false_alarm_rate", "miss_rate")


@dataclass(frozen=True)
class AdviceThresholds:
    """Equation 2's α and the advisory's window (configs/advisory.toml), which the advice is judged with."""

    alpha_m: float
    window_s: float


def advice_thresholds(directory: Path | None = None) -> AdviceThresholds:
    """α and the window of the advisory's settings (configs/advisory.toml)."""
    from advisory.config import load_advisory_config

    cfg = load_advisory_config(directory)
    return AdviceThresholds(cfg.equation2.alpha_m, cfg.timing.window_s)


def participant_advice(
    per_attempt: list[AttemptMetrics], cfg: MetricsConfig, thresholds: AdviceThresholds
) -> dict[str, float]:
    """Mean speed, false-alarm and miss rates (``study.advice``) of a participant's attempts, pooled."""
    length = duration = 0.0
    outcome = AdviceOutcome()
    for a in per_attempt:
        offset = wall_to_camera_offset(a.folder)
        events = read_events(a.folder)
        reference = _read_poses(a.folder / "groundtruth.tum")
        start = events.loc[events.kind == "initialised", "time"]
        objects = events.loc[events.kind == "object", "time"]
        begin = float(start.min()) + offset if not start.empty else float(a.rpe.timestamps.min(initial=np.inf))
        end = task_end_s(a.folder)
        end = end if end is not None else float(objects.max()) + offset if not objects.empty else np.inf
        if reference is not None:
            metres, seconds = path_speed(reference, begin, end, cfg.speed_sample_s)
            length, duration = length + metres, duration + seconds
        advisory = a.folder / ADVISORY_CSV
        log = read_csv_log(advisory) if advisory.exists() else pd.DataFrame()
        # An advisory log of another layout (an older advisory's, a hand-made one) is not judged.
        if {"wall_time", "played_pulses"} <= set(log.columns):
            log = log.dropna(subset=["wall_time", "played_pulses"])
            outcome = outcome + advice_outcome(
                log,
                a.rpe.timestamps,
                a.rpe.errors_m,
                offset,
                thresholds.window_s,
                thresholds.alpha_m,
                cfg.advice_high_error_m,
                None if not np.isfinite(end) else end,
            )
    return {
        "mean_speed_mps": length / duration if duration > 0 else np.nan,
        "warning_share": outcome.warning_share,
        "buffers": outcome.buffers,
        "false_alarm_rate": outcome.false_alarm_rate,
        "miss_rate": outcome.miss_rate,
    }


def collect_study(study: Path, cfg: MetricsConfig, thresholds: AdviceThresholds) -> StudyData:
    """Metrics of every participant and condition of the analysed phase (participants without data have NaN),
    with the advice's cost and accuracy (:func:`participant_advice`)."""
    protocol = read_protocol(study)
    rows, pair_rows, attempts = [], [], {}
    for person in protocol.participants:
        for position, condition in enumerate(person.conditions, start=1):
            folder = protocol.phase_folder(study, person.id, protocol.analysed_phase, condition)
            result = participant_metrics(used_attempts(folder), cfg)
            row = {
                "participant": person.id,
                "condition": condition,
                "position": position,
                "status": phase_status(folder),
                "attempts": len(used_attempts(folder)),
            }
            if result is None:
                row.update(dict.fromkeys(METRIC_COLUMNS + ADVICE_COLUMNS, np.nan))
            else:
                metrics, per_attempt = result
                row.update({c: getattr(metrics, c) for c in METRIC_COLUMNS})
                row.update(participant_advice(per_attempt, cfg, thresholds))
                attempts[(person.id, condition)] = per_attempt
                for a in per_attempt:
                    pair_rows.append(
                        pd.DataFrame(
                            {
                                "participant": person.id,
                                "condition": condition,
                                "attempt": a.folder.name,
                                "timestamp": a.rpe.timestamps,
                                "error_m": a.rpe.errors_m,
                            }
                        )
                    )
            rows.append(row)
    pairs = (
        pd.concat(pair_rows, ignore_index=True)
        if pair_rows
        else pd.DataFrame(columns=["participant", "condition", "attempt", "timestamp", "error_m"])
    )
    return StudyData(protocol, pd.DataFrame(rows), pairs, attempts)
