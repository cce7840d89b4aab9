"""A whole simulated study: its protocol, its sessions run in parallel child processes, resumable.

The study folder is a study of the kit (``protocol.json``, ``participants/<id>/<phase>/attempt-<n>/``) with one
phase, ``task``, and ``simulation.json``: the simulation settings (configs/simulate.toml as resolved) and the model
version it was made with. Running the command again on the same folder resumes it: every session whose phase is
done is kept, the others run (a session cut short by Ctrl-C or a crash leaves its attempt, marked, and the next
attempt, which supersedes it, starts from the beginning: a session is a few minutes of simulated time). Resuming with
other settings or another model is refused, naming what differs.

Each session runs as a child command, ``seesys study simulate-session`` (:func:`run_session`), under the session
supervisor that ``seesys run`` and ``seesys study run`` use too (:mod:`seesys.io.supervision`), ``processes`` at a
time, each with its output in the study's ``logs/<participant>-<condition>.log`` and ORB-SLAM3's console output in
its attempt's ``orbslam3.log``. The child reads the session's settings from ``simulation.json`` and the other
settings from the study's ``configs/`` (the configuration the study was run with). A session that ends with its
task completed or timed out is done; one whose child fails with a SEESys error (status 2: a model made for another
device, settings that cannot work) fails at once; a crash of ORB-SLAM3 (it aborts on rare degenerate frames) or a
hang (no frame in ``frames.csv`` for ``stall_timeout_s``: the child is killed) costs one attempt, and the session
runs again, in a new attempt, up to ``retries`` times. Ctrl-C stops every session: each ends ``interrupted`` with
its files final.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from advisory.conditions import Condition
from estimator.service.model import model_version
from seesys.core.errors import SeesysError
from seesys.core.session_layout import FRAMES_CSV
from seesys.io.children import last_line
from seesys.io.config import CONFIG_DIR_ENV, ConfigSet, as_dict, build
from seesys.io.logfiles import write_json_atomically
from seesys.io.supervision import DONE as EXITED_DONE
from seesys.io.supervision import FAILED, Exit, PartSpec, SupervisionPolicy, Supervisor, exit_text
from seesys_app.simulate.config import CONDITIONS, SimulateConfig, load_simulate_config
from seesys_app.simulate.session import Participant, simulate_session
from seesys_app.simulate.yoking import YOKED_TO, partner_folder, recorded_advice
from study.config import load_study_config
from study.protocol import Protocol, make_protocol, read_protocol, write_protocol
from study.sessions import (
    ATTEMPT,
    DONE,
    RUN_JSON,
    attempt_folders,
    next_attempt_folder,
    phase_status,
    read_run,
    supersede_attempts,
)

SIMULATION_JSON = "simulation.json"
PHASE = "task"
# The study's settings that do not change what a session is (left out of simulation.json, not compared on resume).
RUN_ONLY = ("processes", "retries", "stall_timeout_s")
# The folder of the study's copy of the configuration its session children run with.
CONFIGS = "configs"
# Seconds a session child gets to finish its files after Ctrl-C before it is killed.
STOP_GRACE_S = 2.0
# How often (s) the study looks at its sessions: their exits, their progress, the jobs that may start.
POLL_S = 0.5
# A session child's exit status: a SEESys error (bad model, bad settings: not retried).
SESSION_ERROR = 2
# What the command line prints before a SEESys error (seesys_app.cli.main); the reason of a session is the rest.
ERROR_PREFIX = "seesys: error: "


@dataclass(frozen=True)
class Job:
    participant: Participant
    folder: Path  # the phase folder; each try is a new attempt in it
    after: Path | None = None  # a phase folder that must be done before this job may start (its partner's)

    @property
    def name(self) -> str:
        """How the session is shown: "P03 seesys"."""
        return f"{self.participant.id} {self.participant.condition}"

    @property
    def part(self) -> str:
        """Its child's name for the supervisor (and its log, ``logs/P03-seesys.log``)."""
        return f"{self.participant.id}-{self.participant.condition}"


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
    conditions = cfg.study.conditions
    if Condition.YOKED.value in conditions and YOKED_TO not in conditions:
        raise SeesysError(f"the yoked condition replays the {YOKED_TO} sessions of the study: add {YOKED_TO}")
    record = simulation_record(cfg, model)
    record["settings"]["study"] = {k: v for k, v in record["settings"]["study"].items() if k not in RUN_ONLY}
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
        known=CONDITIONS,
    )
    write_protocol(study, protocol)
    write_json_atomically(path, record)
    return protocol


def pending_jobs(study: Path, protocol: Protocol) -> tuple[list[Job], int]:
    """The sessions not done yet and how many sessions the study has. A ``yoked`` session waits for the ``seesys``
    session it replays (:mod:`seesys_app.simulate.yoking`), so the sessions some other one waits for come first,
    then the rest, each part in participant order: otherwise the last partners of a study run one at a time, with
    processes free and nothing they may start."""
    jobs, total = [], 0
    for number, person in enumerate(protocol.participants, start=1):
        for condition in person.conditions:
            total += 1
            folder = protocol.phase_folder(study, person.id, PHASE, condition)
            if phase_status(folder) != DONE:
                after = partner_folder(study, protocol, PHASE, person.id) if condition == Condition.YOKED else None
                jobs.append(Job(Participant(person.id, number, condition), folder, after))
    waited_for = {job.after for job in jobs}
    return sorted(jobs, key=lambda job: job.folder not in waited_for), total


def recorded_settings(study: Path) -> SimulateConfig:
    """The settings the sessions of ``study`` run with: those its ``simulation.json`` records, with the run-only
    ones it leaves out (which no session reads) from configs/simulate.toml. SeesysError when the study has no
    readable record; ConfigError naming a recorded key that does not fit the settings."""
    path = Path(study) / SIMULATION_JSON
    try:
        settings = json.loads(path.read_text())["settings"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SeesysError(f"{study} is not a simulated study ({path}: {e})") from None
    defaults = as_dict(load_simulate_config().study)
    settings["study"] = {**{key: defaults[key] for key in RUN_ONLY}, **settings["study"]}
    return build(SimulateConfig, settings, str(path))


def study_session(study: Path, participant_id: str, condition: str) -> tuple[Participant, Path]:
    """A session of the study's protocol: its participant (numbered as :func:`pending_jobs` numbers them) and its
    phase folder. SeesysError naming a participant the protocol does not have, or a condition it does not do."""
    protocol = read_protocol(study)
    person = protocol.participant(participant_id)
    if condition not in person.conditions:
        raise SeesysError(f"{participant_id} of {study} does not do the {condition} condition")
    number = protocol.participants.index(person) + 1
    return Participant(person.id, number, condition), protocol.phase_folder(study, person.id, PHASE, condition)


@contextlib.contextmanager
def _output_to(log: Path) -> Iterator[None]:
    """This process's stdout and stderr (file descriptors 1 and 2, where ORB-SLAM3 writes) appended to ``log``
    while inside; restored after, so that an error is printed where the supervisor reads its child's last line."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    target = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(target, 1)
        os.dup2(target, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)
        os.close(target)


def run_session(study: Path, participant_id: str, condition: str, model: Path, stop: Callable[[], bool]) -> str:
    """One session of ``study``, what its child (``seesys study simulate-session``) does: the earlier attempts of
    the session superseded, a new attempt made and simulated with ORB-SLAM3's console output in its
    ``orbslam3.log``; the session's status (``completed``, ``timed_out``, or ``interrupted`` once ``stop()`` is
    true). SeesysError for a participant or condition the study does not have, settings that do not fit, or a
    model made for another device."""
    cfg = recorded_settings(study)
    participant, folder = study_session(study, participant_id, condition)
    recording = None
    if condition == Condition.YOKED:
        recording = recorded_advice(partner_folder(study, read_protocol(study), PHASE, participant_id))
    # An earlier attempt cut short leaves the metrics: the session runs again from its start.
    supersede_attempts(folder)
    attempt = next_attempt_folder(folder)
    with _output_to(attempt / "orbslam3.log"):
        return simulate_session(cfg, participant, attempt, model, None, None, stop, recording).status


def _mark_crashed(attempt: Path, reason: str) -> None:
    """Record in ``run.json`` that an attempt's process died (``reason``), unless the session recorded its end."""
    try:
        run = json.loads((attempt / RUN_JSON).read_text())
    except (OSError, ValueError):
        run = {}
    if run.get("status") in (None, "running"):
        run.update(status="failed", error=reason)
        write_json_atomically(attempt / RUN_JSON, run)


def _next_attempt(folder: Path) -> Path:
    """The attempt a session child started now makes in ``folder`` (numbered as ``next_attempt_folder`` does)."""
    attempts = attempt_folders(folder)
    match = ATTEMPT.match(attempts[-1].name) if attempts else None
    return folder / f"attempt-{int(match.group(1)) + 1 if match else 1}"


def _simulated_seconds(frames: Path) -> float:
    """Simulated time from the first frame of a growing ``frames.csv`` to its last complete one (0: none yet)."""
    try:
        with frames.open() as f:
            f.readline()  # the header
            first = f.readline().split(",")
        return max(0.0, float(last_line(frames).split(",")[1]) - float(first[1]))
    except (OSError, IndexError, ValueError):
        return 0.0


@dataclass
class _Session:
    """A job whose child runs: the attempt its current try writes, and the simulated seconds last shown."""

    job: Job
    attempt: Path
    shown: float = 0.0

    def progress(self) -> int | None:
        """The size of the attempt's ``frames.csv`` (a row a frame; None before it exists): the child's progress."""
        try:
            return (self.attempt / FRAMES_CSV).stat().st_size
        except OSError:
            return None


class _StudyRun:
    """The sessions of one run of a study: started as children of one Supervisor, at most ``processes`` at a
    time and each once its partner is done, restarted after a crash or a hang, reported through ``show``."""

    def __init__(
        self,
        study: Path,
        cfg: SimulateConfig,
        model: Path,
        env: dict[str, str],
        show: Callable[[str, float, str], None],
    ):
        self.study, self.model, self.show = study, model, show
        self.processes, self.stall_timeout_s = cfg.study.processes, cfg.study.stall_timeout_s
        policy = SupervisionPolicy(
            ready_timeout_s=0.0,
            poll_s=min(POLL_S, cfg.study.stall_timeout_s),
            restart_delay_s=0.0,
            max_restarts=cfg.study.retries,
            stop_timeout_s=STOP_GRACE_S,
            device_stop_timeout_s=STOP_GRACE_S,
            fatal_status=SESSION_ERROR,
            stall_timeout_s=cfg.study.stall_timeout_s,
        )
        self.supervisor = Supervisor(study, env, policy, lambda part, event, detail: None)
        self.queue: list[Job] = []
        self.running: dict[str, _Session] = {}  # by the child's name
        self.failed: list[str] = []

    def run(self, jobs: list[Job]) -> list[str]:
        """Run ``jobs`` until each is done or has failed; the failures ("P03 seesys: why"). A KeyboardInterrupt
        stops every session (see :meth:`stop`) and is raised again."""
        self.queue = list(jobs)
        try:
            while self.queue or self.running:
                for noticed in self.supervisor.look():
                    self._exited(self.running[noticed.name], noticed)
                self._start_jobs()
                self._show_progress()
                time.sleep(self.supervisor.policy.poll_s)
        except KeyboardInterrupt:
            self.stop()
            raise
        return self.failed

    def _start_jobs(self) -> None:
        """Start the queued jobs whose partner is done, in order, while processes are free; fail those whose
        partner failed (or waits for them: nothing runs and no job could start)."""
        for job in list(self.queue):
            if job.after is None or phase_status(job.after) == DONE:
                if len(self.running) < self.processes:
                    self.queue.remove(job)
                    self._start(job)
            elif not self._to_run(job.after):
                self.queue.remove(job)
                self._fail(job, "its partner's session failed")
        if self.queue and not self.running:
            for job in self.queue:
                self._fail(job, "its partner's session waits for it")
            self.queue.clear()

    def _to_run(self, folder: Path) -> bool:
        """Whether a session of this run (queued or running) is the one of ``folder``."""
        return any(job.folder == folder for job in self.queue) or any(
            session.job.folder == folder for session in self.running.values()
        )

    def _start(self, job: Job) -> None:
        session = self.running[job.part] = _Session(job, _next_attempt(job.folder))
        args = (
            *("study", "simulate-session", "--study", str(self.study)),
            *("--participant", job.participant.id, "--condition", job.participant.condition),
            *("--model", str(self.model)),
        )
        self.supervisor.start(PartSpec(job.part, args, restartable=True, finishes=True, progress=session.progress))
        self.show(job.name, 0.0, session.attempt.name)

    def _exited(self, session: _Session, noticed: Exit) -> None:
        """A session child's exit: the session done, failed for good, or run again in a new attempt."""
        name = session.job.name
        if noticed.outcome == EXITED_DONE:
            del self.running[noticed.name]
            self.show(name, 0.0, str(read_run(session.attempt).get("outcome", "completed")))
            return
        reason = self._reason(noticed)
        if noticed.status != SESSION_ERROR:
            # A child that died before it made its attempt still had one: each try is an attempt that says how it
            # ended. One refused by a SEESys error (an unknown participant, say) made none when it refused.
            session.attempt.mkdir(parents=True, exist_ok=True)
        if session.attempt.is_dir():
            _mark_crashed(session.attempt, reason)
        if noticed.outcome == FAILED:
            del self.running[noticed.name]
            self.failed.append(f"{name}: {reason}")
            self.show(name, 0.0, f"failed: {reason}")
            return
        self.show(name, 0.0, f"{reason}; once more")
        # The supervisor starts the child again at its next look; that try makes the next attempt.
        session.attempt, session.shown = _next_attempt(session.job.folder), 0.0
        self.show(name, 0.0, session.attempt.name)

    def _reason(self, noticed: Exit) -> str:
        """Why a session child ended without its session done, in words."""
        if noticed.stalled:
            return f"no frame for {self.stall_timeout_s:g} s: hung, killed"
        if noticed.status == SESSION_ERROR and noticed.last_line:
            return noticed.last_line.removeprefix(ERROR_PREFIX)
        last = f": {noticed.last_line}" if noticed.last_line else ""
        return f"its process ended ({exit_text(noticed.status)}){last}"

    def _fail(self, job: Job, reason: str) -> None:
        self.failed.append(f"{job.name}: {reason}")
        self.show(job.name, 0.0, f"failed: {reason}")

    def _show_progress(self) -> None:
        """Each running session's simulated seconds, shown once a second more is simulated."""
        for session in self.running.values():
            seconds = _simulated_seconds(session.attempt / FRAMES_CSV)
            if seconds >= session.shown + 1.0:
                session.shown = seconds
                self.show(session.job.name, seconds, "")

    def stop(self) -> None:
        """Stop every session child: each is told (SIGTERM) and given STOP_GRACE_S to end its session at a frame
        boundary with its files final; one that has not is killed and its attempt marked failed."""
        exits = self.supervisor.stop()
        for part, session in self.running.items():
            if exits.get(part) == -signal.SIGKILL and session.attempt.is_dir():
                _mark_crashed(session.attempt, f"stopped: killed after {STOP_GRACE_S:g} s")


def run_study(
    study: Path,
    cfg: SimulateConfig,
    model: Path,
    config_dir: Path | None = None,
    show: Callable[[str, float, str], None] | None = None,
) -> StudyOutcome:
    """Simulate every session of ``study`` not done yet, ``cfg.study.processes`` at a time, each job once its
    ``after`` session is done. A ``KeyboardInterrupt`` (Ctrl-C; SIGTERM where the caller maps it so, as the command
    does) stops every session (``interrupted``, files final) and is raised again.

    The session children run with the configuration of ``config_dir`` (default: the one in use), copied into the
    study's ``configs/``. ``show(session, simulated_seconds, note)`` reports each session ("P03 seesys"): its start
    (0 s, note "attempt-1"), its progress (note "") and its end (note "completed", "timed_out", "failed: why",
    ...)."""
    study = Path(study)
    protocol = prepare_study(study, cfg, model)
    jobs, total = pending_jobs(study, protocol)
    configs = ConfigSet.read(config_dir).write(study / CONFIGS)
    env = {**os.environ, CONFIG_DIR_ENV: str(configs)}
    failed = _StudyRun(study, cfg, model, env, show or (lambda name, seconds, note: None)).run(jobs)
    done = sum(
        1
        for person in protocol.participants
        for condition in person.conditions
        if phase_status(protocol.phase_folder(study, person.id, PHASE, condition)) == DONE
    )
    return StudyOutcome(study, total, done, failed)
