"""A whole simulated study: its protocol, its sessions run in parallel processes, resumable.

The study folder is a study of the kit (``protocol.json``, ``participants/<id>/<phase>/attempt-<n>/``) with one
phase, ``task``, and ``simulation.json``: the simulation settings (configs/simulate.toml as resolved) and the model
version it was made with. Running the command again on the same folder resumes it: every session whose phase is
done is kept, the others run (a session cut short by Ctrl-C or a crash leaves its attempt, marked, and the next
attempt, which supersedes it, starts from the beginning: a session is a few minutes of simulated time). Resuming with
other settings or another model is refused, naming what differs.

Each session runs in its own process (spawned), so that a crash of ORB-SLAM3 (it aborts on rare degenerate frames)
or a hang (a session that reports no frame for ``stall_timeout_s`` is killed) costs one attempt, which is retried
up to ``retries`` times, and ORB-SLAM3's console output goes to the attempt's
``orbslam3.log`` (with anything else the process prints). Ctrl-C stops every session: each ends ``interrupted`` with
its files final.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection, wait
from multiprocessing.context import SpawnProcess
from pathlib import Path
from typing import cast

from estimator.service.model import model_version
from seesys.core.errors import SeesysError
from seesys.io.config import as_dict
from seesys.io.logfiles import write_json_atomically
from seesys_app.simulate.config import SimulateConfig
from seesys_app.simulate.session import Participant, simulate_session
from study.config import load_study_config
from study.protocol import Protocol, make_protocol, read_protocol, write_protocol
from study.sessions import DONE, RUN_JSON, next_attempt_folder, phase_status, supersede_attempts

SIMULATION_JSON = "simulation.json"
PHASE = "task"
# Seconds a session process gets to finish its files after Ctrl-C before it is terminated.
STOP_GRACE_S = 2.0
# How often (s) the study looks for a hung session while none reports.
WATCH_S = 5.0


@dataclass(frozen=True)
class Job:
    participant: Participant
    folder: Path  # the phase folder; each try is a new attempt in it


@dataclass(frozen=True)
class StudyOutcome:
    study: Path
    sessions: int  # sessions of the study
    done: int
    failed: list[str]  # "P03 seesys: why"


def simulation_record(cfg: SimulateConfig, model: Path) -> dict:
    """What makes a simulated study what it is: its settings and model (compared on resume)."""
    return {"settings": json.loads(json.dumps(as_dict(cfg))), "model_version": model_version(model)}


def _differences(recorded: object, wanted: object, where: str = "") -> list[str]:
    """Where two JSON values differ, as "key.key (recorded there, wanted now)"; tables compared key by key."""
    if isinstance(recorded, dict) and isinstance(wanted, dict):
        out = []
        for key in sorted(set(recorded) | set(wanted)):
            out += _differences(recorded.get(key), wanted.get(key), f"{where}.{key}" if where else key)
        return out
    return [] if recorded == wanted else [f"{where} ({recorded!r} there, {wanted!r} now)"]


def prepare_study(study: Path, cfg: SimulateConfig, model: Path) -> Protocol:
    """The study's protocol: drawn and written for a new folder, read (after checking that the settings and model
    are those it was made with) for an existing one."""
    study = Path(study)
    record = simulation_record(cfg, model)
    # The session count, process count and retries do not change what a session is.
    ignored = ("processes", "retries", "stall_timeout_s")
    record["settings"]["study"] = {k: v for k, v in record["settings"]["study"].items() if k not in ignored}
    path = study / SIMULATION_JSON
    if path.exists():
        recorded = json.loads(path.read_text())
        differences = _differences(recorded, record)
        if differences:
            raise SeesysError(
                f"{study} was simulated with other settings or another model; differing: "
                f"{'; '.join(differences[:5])} (use a new folder, or the settings it records in "
                f"{path})"
            )
        return read_protocol(study)
    protocol_cfg = replace(load_study_config().protocol, phases=[PHASE], objects=cfg.task.objects)
    protocol = make_protocol(
        protocol_cfg,
        cfg.study.participants_per_condition,
        cfg.study.design,
        cfg.study.operator_seed,
        list(cfg.study.conditions),
    )
    write_protocol(study, protocol)
    write_json_atomically(path, record)
    return protocol


def pending_jobs(study: Path, protocol: Protocol) -> tuple[list[Job], int]:
    """The sessions not done yet, in participant order, and how many sessions the study has."""
    jobs, total = [], 0
    for number, person in enumerate(protocol.participants, start=1):
        for condition in person.conditions:
            total += 1
            folder = protocol.phase_folder(study, person.id, PHASE, condition)
            if phase_status(folder) != DONE:
                jobs.append(Job(Participant(person.id, number, condition), folder))
    return jobs, total


def _session_process(
    cfg: SimulateConfig, participant: Participant, attempt: Path, model: Path, config_dir: Path | None, progress
) -> None:
    """A session's process: ORB-SLAM3's console output into the attempt's log, progress to the parent."""
    import cv2

    # Ctrl-C and SIGTERM end the session at its next frame with its files final, even where the process was
    # started with SIGINT ignored (a background job of a shell script). A flag, not KeyboardInterrupt: an exception
    # could land between a frame's rows and its count, or in the closing of the files.
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    cv2.setNumThreads(1)  # parallelism is across sessions: OpenCV's own threads would only contend with them
    attempt.mkdir(parents=True, exist_ok=True)
    log = os.open(attempt / "orbslam3.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(log, 1)
    os.dup2(log, 2)
    last = [-1.0]

    def on_frame(_: int, t: float) -> None:
        if t - last[0] >= 1.0:
            last[0] = t
            progress.send(t)

    try:
        outcome = simulate_session(cfg, participant, attempt, model, config_dir, on_frame, stop.is_set)
        progress.send(("done", outcome.status))
    except SeesysError as e:
        progress.send(("error", str(e)))
        raise SystemExit(2) from None


def _mark_crashed(attempt: Path, reason: str) -> str:
    """Record in ``run.json`` that an attempt's process died (``reason``), and return the reason."""
    try:
        run = json.loads((attempt / RUN_JSON).read_text())
    except (OSError, ValueError):
        run = {}
    if run.get("status") in (None, "running"):
        run.update(status="failed", error=reason)
        write_json_atomically(attempt / RUN_JSON, run)
    return reason


def run_study(
    study: Path,
    cfg: SimulateConfig,
    model: Path,
    config_dir: Path | None = None,
    show: Callable[[str, float, str], None] | None = None,
) -> StudyOutcome:
    """Simulate every session of ``study`` not done yet, ``cfg.study.processes`` at a time. A
    ``KeyboardInterrupt`` (Ctrl-C; SIGTERM where the caller maps it so, as the command does) stops every session
    (``interrupted``, files final) and is raised again.

    ``show(session, simulated_seconds, note)`` reports each session ("P03 seesys"): its start (0 s, note
    "attempt-1"), its progress (note "") and its end (note "completed", "timed_out", "failed: why", ...)."""
    protocol = prepare_study(study, cfg, model)
    jobs, total = pending_jobs(study, protocol)
    context = multiprocessing.get_context("spawn")
    queue = list(jobs)
    tries: dict[str, int] = {}
    running: dict[Connection, tuple[Job, Path, SpawnProcess, str]] = {}  # by the session's progress pipe
    # A session reports every simulated second; one silent for stall_timeout_s is hung (ORB-SLAM3 has been seen to
    # hang in a map reset after a loss): it is killed and counts as a crash.
    last_heard: dict[Connection, float] = {}
    stalled: set[Connection] = set()
    failed: list[str] = []
    report = show or (lambda name, seconds, note: None)
    try:
        while queue or running:
            while queue and len(running) < cfg.study.processes:
                job = queue.pop(0)
                name = f"{job.participant.id} {job.participant.condition}"
                tries[name] = tries.get(name, 0) + 1
                # An earlier attempt cut short leaves the metrics: the session runs again from its start.
                supersede_attempts(job.folder)
                attempt = next_attempt_folder(job.folder)
                receiver, sender = context.Pipe(duplex=False)
                process = context.Process(
                    target=_session_process,
                    name=f"simulate {name}",
                    args=(cfg, job.participant, attempt, model, config_dir, sender),
                )
                process.start()
                sender.close()
                running[receiver] = (job, attempt, process, name)
                last_heard[receiver] = time.monotonic()
                report(name, 0.0, attempt.name)
            # wait() returns those of the given pipes that are ready (typeshed: any waitable).
            ready = cast(list[Connection], wait(list(running), timeout=min(WATCH_S, cfg.study.stall_timeout_s)))
            now = time.monotonic()
            for receiver, (_, _, process, _) in running.items():
                if receiver not in ready and now - last_heard[receiver] > cfg.study.stall_timeout_s:
                    stalled.add(receiver)
                    process.kill()  # its pipe closes: handled as a crash on the next look
            for receiver in ready:
                job, attempt, process, name = running[receiver]
                last_heard[receiver] = now
                try:
                    message = receiver.recv()
                except EOFError:
                    message = None
                if isinstance(message, float):
                    report(name, message, "")
                    continue
                process.join()
                receiver.close()
                del running[receiver], last_heard[receiver]
                if message == ("done", "completed") or message == ("done", "timed_out"):
                    report(name, 0.0, message[1])
                    continue
                hung = receiver in stalled
                stalled.discard(receiver)
                reason = (
                    message[1]
                    if isinstance(message, tuple) and message[0] == "error"
                    else _mark_crashed(
                        attempt,
                        f"no frame for {cfg.study.stall_timeout_s:g} s: hung, killed"
                        if hung
                        else f"its process ended with exit code {process.exitcode}",
                    )
                )
                if isinstance(message, tuple) and message[0] == "error" or tries[name] > cfg.study.retries:
                    failed.append(f"{name}: {reason}")
                    report(name, 0.0, f"failed: {reason}")
                else:
                    report(name, 0.0, f"{reason}; once more")
                    queue.append(job)
    except KeyboardInterrupt:
        # A terminal's Ctrl-C reaches every session already; SIGTERM to this process, or a Ctrl-C it alone got,
        # does not: each session is told, then given STOP_GRACE_S to close its files.
        for _job, _attempt, process, _name in running.values():
            if process.is_alive() and process.pid is not None:  # alive: started, so it has a pid
                os.kill(process.pid, signal.SIGINT)
        for _job, attempt, process, _name in running.values():
            process.join(STOP_GRACE_S)
            if process.is_alive():
                process.terminate()
                process.join()
                _mark_crashed(attempt, f"stopped: terminated after {STOP_GRACE_S:g} s")
        raise
    done = sum(
        1
        for person in protocol.participants
        for condition in person.conditions
        if phase_status(protocol.phase_folder(study, person.id, PHASE, condition)) == DONE
    )
    return StudyOutcome(Path(study), total, done, failed)
