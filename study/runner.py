"""``seesys study run``: one participant's session in one phase, composed of the existing commands.

Each run writes a new attempt folder (``study.sessions``) and, as child processes of the session supervisor that
``seesys run`` uses too (``seesys.io.supervision``):

- the device: ``seesys monitor run --stream`` (ORB-SLAM3 + RTS monitor, publishing the feature stream), writing
  its session files into the attempt folder;
- the advisory in the participant's condition: ``seesys advisory run --condition C``;
- the motion-capture logger: ``seesys study mocap log`` (``mocap.tum``);
- optionally an estimate source: ``seesys advisory replay --estimates CSV`` (until the estimator service runs
  on the edge server, or for dry runs), started with the advisory and sending from the device's first frame on
  (``replay_sent.csv``: when it sent each estimate).

In the runner itself, a thread logs every estimate it receives (``study.watch``), another reads the operator's
event keys (``study.operator``) into ``events.csv``, and a status line shows the tracking state, the latest
estimate, the advisory's pulses, the mocap rate and the frames the device could not publish. Every child runs with
the attempt's copy of the configs (``configs/``); in an audible condition on a machine without a sound card the
advisory plays into a JACK dummy server the runner starts, as ``seesys run`` does (``advisory.output``).

The session ends when the device's source ends (``completed``), when the operator presses ``q`` (``stopped``: the
task ended then; ``run.json`` ``task_end`` and an event ``task_end`` give the time and the last frame logged by
then, and the frames the device logs after it stay in the session, outside the task's metrics), or on Ctrl-C or
SIGTERM (``interrupted``). The device then gets SIGINT: it ends its source, closes its files and says so in
``session.json`` (``interrupted``), normally within a second; one that has not exited after
``device_interrupt_timeout_s`` is terminated. The other children are stopped after it. ``run.json`` says
``running`` (with the runner's pid) until then and the outcome after; every log is appended line by line and
flushed, so a runner killed at any moment leaves files that parse (its children die with it). A run that fails
before the device logged a frame (a part that does not start, no audio, no camera) is no attempt: its folder is
renamed ``failed-start-<UTC time>``. Without a ground truth from the source, the mocap is calibrated into
``groundtruth.tum`` at the end (``study.mocap.calibrate``).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import queue
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

from rich.console import Console
from rich.live import Live
from rich.text import Text

from advisory import config as advisory_config
from advisory.conditions import Condition
from advisory.config import load_advisory_config
from advisory.estimate_log import read_estimate_log
from advisory.output import AudioOutput, open_audio_output
from seesys.core.errors import SeesysError
from seesys.core.session_layout import ADVISORY_COLUMNS, ADVISORY_CSV
from seesys.io.children import RowCounter, last_line
from seesys.io.config import CONFIG_DIR_ENV, ConfigSet
from seesys.io.logfiles import CsvLog, write_json_atomically
from seesys.io.network import load_network_config
from seesys.io.processes import stop_on_signals
from seesys.io.session_files import utc_now
from seesys.io.supervision import PartSpec, SupervisionPolicy, Supervisor
from slam_monitor import monitor_config
from slam_monitor.monitor_config import load_monitor_config, resolve_device_id
from study.config import StudyConfig
from study.mocap.calibrate import CALIBRATION_JSON, GROUND_TRUTH, MOCAP_LOG, calibrate_session
from study.mocap.logger import CLOCKS, MOCAP_STATS
from study.operator import KEYS_HELP, OperatorEvent, OperatorInput
from study.protocol import Protocol, ProtocolError, read_protocol
from study.sessions import (
    DONE,
    DONE_STATUSES,
    EVENTS_CSV,
    RUN_JSON,
    next_attempt_folder,
    phase_status,
    read_run,
    set_aside_failed_start,
    supersede_attempts,
)
from study.watch import StreamWatcher

EVENT_COLUMNS = ("time", "kind", "detail")
CONFIGS = "configs"
# How long the runner waits for its subscriber sockets before starting the publishers.
SUBSCRIBER_READY_S = 5.0
REPLAY_SENT_CSV = "replay_sent.csv"  # the estimate replay's send times (its file is its "ready")


@dataclass(frozen=True)
class RunOptions:
    study: Path
    participant: str
    phase: str
    condition: str | None = None
    source: str | None = None
    mode: str | None = None
    replay_estimates: Path | None = None
    restart: bool = False
    max_frames: int | None = None
    pace: bool | None = None
    record_mocap: bool | None = None


@dataclass(frozen=True)
class RunResult:
    attempt: Path
    status: str
    frames: int
    estimates: int
    events: int


def choose_condition(protocol: Protocol, study: Path, participant: str, phase: str, condition: str | None) -> str:
    """The participant's condition; within-subjects, the first of their order not yet done (or ``condition``)."""
    person = protocol.participant(participant)
    if condition is not None:
        if condition not in person.conditions:
            raise ProtocolError(
                f"{participant} is not assigned condition {condition!r} ({', '.join(person.conditions)})"
            )
        return condition
    for c in person.conditions:
        if phase_status(protocol.phase_folder(study, participant, phase, c)) != DONE:
            return c
    return person.conditions[-1]


class Session:
    """One run of ``seesys study run`` (see the module docstring)."""

    def __init__(self, options: RunOptions, cfg: StudyConfig, operator: OperatorInput, console: Console):
        self.o, self.cfg, self.operator, self.console = options, cfg, operator, console
        self.protocol = read_protocol(options.study)
        if options.phase not in self.protocol.phases:
            raise ProtocolError(
                f"unknown phase {options.phase!r} (the protocol's phases: {', '.join(self.protocol.phases)})"
            )
        self.condition = choose_condition(
            self.protocol, options.study, options.participant, options.phase, options.condition
        )
        self.phase_folder = self.protocol.phase_folder(
            options.study, options.participant, options.phase, self.condition
        )
        if phase_status(self.phase_folder) == DONE and not options.restart:
            raise SeesysError(
                f"{options.participant} has done {options.phase} ({self.condition}) already "
                f"({self.phase_folder}); pass --restart to record it again (the earlier attempts "
                f"are kept, marked superseded)"
            )
        self.source = options.source or cfg.runner.source
        # The advisory and the watcher listen to this device alone (or to the replayed log's device id); the id is
        # decided here and given to the device (its configs).
        self.monitor = load_monitor_config()
        self.device_id = resolve_device_id(self.monitor.device_id, self.source)
        self.estimates_from = (
            load_advisory_config().replay.replay_device_id if options.replay_estimates is not None else None
        )
        self.mode = options.mode or cfg.runner.mode
        if options.replay_estimates is not None:
            read_estimate_log(options.replay_estimates)  # a bad log is refused before anything starts
        self.supervisor: Supervisor | None = None  # once the children start
        self.output: AudioOutput | None = None
        self.env: dict[str, str] | None = None
        self.frames = self.advisory_rows = lambda: 0
        self.objects = 0
        self.events_logged = 0
        self.pulses = "–"

    def _run_json(self, **changes: object) -> None:
        run = read_run(self.attempt) if (self.attempt / RUN_JSON).exists() else {}
        run.update(changes)
        write_json_atomically(self.attempt / RUN_JSON, run)

    def _event(self, log: CsvLog, kind: str, detail: str = "", at: float | None = None) -> None:
        log.write(time.time() if at is None else at, kind, detail)
        self.events_logged += 1

    def _status_line(self, watcher: StreamWatcher) -> Text:
        row = last_line(self.attempt / "frames.csv").split(",")
        state = row[2] if len(row) > 2 else "starting"
        advisory = last_line(self.attempt / ADVISORY_CSV).split(",")
        if len(advisory) == len(ADVISORY_COLUMNS):
            self.pulses = advisory[ADVISORY_COLUMNS.index("n_pulses")]
        try:
            stats = json.loads((self.attempt / MOCAP_STATS).read_text())
            # The body unseen for two stats intervals: occluded markers or a wrong body name, worth the operator's eye.
            last = stats["last_pose_time"]
            unseen = last is None or CLOCKS[self.cfg.mocap.clock]() - last > 2 * self.cfg.mocap.stats_interval_s
            mocap = "NO BODY" if unseen else f"{stats['rate_hz']:.0f} Hz"
        except (OSError, ValueError, KeyError, TypeError):
            mocap = "–" if self.record_mocap else "off"
        estimate = "–" if math.isnan(watcher.latest_error_m) else f"{watcher.latest_error_m * 100:.2f} cm"
        # One line of at most ~80 characters: frames and state, estimate, pulses N, mocap rate, frames dropped
        # (skipped by the device + lost in transit), objects reached.
        return Text(
            f"{self.o.participant} {self.o.phase}/{self.condition}  {self.frames()} {state}  est {estimate}"
            f"  N {self.pulses}  mocap {mocap}  drop {watcher.frames_skipped}+"
            f"{watcher.losses.lost_in_transit}  obj {self.objects}"
        )

    def _policy(self) -> SupervisionPolicy:
        runner = self.cfg.runner
        # Nothing is restarted: a part that exits during a participant's session ends it or is reported.
        return SupervisionPolicy(
            ready_timeout_s=runner.ready_timeout_s,
            poll_s=runner.status_interval_s,
            restart_delay_s=0.0,
            max_restarts=0,
            stop_timeout_s=runner.stop_timeout_s,
            device_stop_timeout_s=runner.device_interrupt_timeout_s,
        )

    def _start_children(self, supervisor: Supervisor, stop: threading.Event) -> None:
        """The advisory, the mocap logger and the estimate replay first; the device once they run, so that the
        participant never starts without audio or ground truth. KeyboardInterrupt when a signal comes meanwhile."""
        first = [
            PartSpec(
                "advisory",
                ("advisory", "run", "--condition", self.condition, "--out", str(self.attempt)),
                ready=lambda: self.advisory_rows() > 0,
            )
        ]
        if self.o.replay_estimates is not None:
            # ready once bound; its schedule starts with the device's first frame, however long its start took
            sent = self.attempt / REPLAY_SENT_CSV
            replay = ("advisory", "replay", "--estimates", str(self.o.replay_estimates), "--sent-log", str(sent))
            first.append(PartSpec("replay", (*replay, "--start-with-device", self.device_id), ready=sent.exists))
        if self.record_mocap:
            first.insert(
                0,
                PartSpec(
                    "mocap",
                    ("study", "mocap", "log", "--out", str(self.attempt)),
                    ready=(self.attempt / MOCAP_STATS).exists,
                ),
            )
        supervisor.start_ready(first, stop)
        device = [
            "monitor",
            "run",
            "--source",
            self.source,
            "--mode",
            self.mode,
            "--out",
            str(self.attempt),
            "--stream",
        ]
        if self.o.max_frames:
            device += ["--max-frames", str(self.o.max_frames)]
        if self.o.pace is not None:
            # a recording standing in for the participant's camera plays in real time, as the camera would
            device.append("--real-time" if self.o.pace else "--no-pace")
        supervisor.start(PartSpec("device", tuple(device), device=True))

    def _handle(self, event: OperatorEvent) -> bool:
        """Act on an operator event (the input thread has logged it); False when it ends the session."""
        if event.kind == "object":
            self.objects = int(event.detail)
        return event.kind != "end"

    def _task_end(self, event: OperatorEvent) -> dict:
        """The end of the task (``q``): when the operator pressed it and the last frame the device had logged by
        then (None: none yet). Frames the device logs after it are kept, outside the task."""
        row = last_line(self.attempt / "frames.csv").split(",")
        frame: int | None
        timestamp: float | None
        try:
            frame, timestamp = int(row[0]), float(row[1])
        except (IndexError, ValueError):
            frame = timestamp = None
        return {"time": event.time, "frame_index": frame, "timestamp": timestamp}

    def _audio(self, events: CsvLog) -> None:
        """The run's configs (``configs/``, what every child runs with) and environment; in an audible condition
        the sound goes to the output device or, without one, to a JACK dummy server started here, as ``seesys
        run`` does (``advisory.output``)."""
        advisory = load_advisory_config()
        timing = replace(advisory.timing, listen_to_device=self.estimates_from or self.device_id)
        if Condition(self.condition).audible:
            self.output = open_audio_output(advisory.audio)
            advisory = replace(advisory, audio=self.output.settings(advisory.audio))
            if self.output.unavailable is not None:
                self.console.print(
                    f"no audio output ({self.output.unavailable}): the advisory plays into a {self.output.description}",
                    markup=False,
                    highlight=False,
                )
            self._event(events, "audio", self.output.description)
            self._run_json(audio=self.output.description)
        config_dir = (
            ConfigSet.read()
            .replaced(advisory_config.SECTION, replace(advisory, timing=timing))
            .replaced(monitor_config.SECTION, replace(self.monitor, device_id=self.device_id))
            .write(self.attempt / CONFIGS)
        )
        self.env = {**os.environ, CONFIG_DIR_ENV: str(config_dir), **(self.output.env() if self.output else {})}

    def _wait_for_the_device(
        self, supervisor: Supervisor, stop: threading.Event, watcher: StreamWatcher, events: CsvLog
    ) -> str | None:
        """Until the device ends (None), the operator ends the task (``stopped``) or a signal comes
        (``interrupted``)."""
        # The status line is drawn on a terminal only; a script or test gets the summary at the end.
        if self.console.is_terminal:
            self.console.print(f"{self.attempt}: {KEYS_HELP}")
        with (
            Live(self._status_line(watcher), console=self.console, transient=True, refresh_per_second=4)
            if self.console.is_terminal
            else contextlib.nullcontext()
        ) as live:
            while supervisor.running("device"):
                if stop.is_set():
                    return "interrupted"
                try:
                    event = self.operator.events.get(timeout=self.cfg.runner.status_interval_s)
                    if not self._handle(event):
                        task_end = self._task_end(event)
                        self._run_json(task_end=task_end)
                        self._event(events, "task_end", f"frame {task_end['frame_index']}", event.time)
                        return "stopped"
                except queue.Empty:
                    pass
                if live is not None:
                    live.update(self._status_line(watcher))
        return None

    def run(self) -> RunResult:
        # Ctrl-C and SIGTERM set `stop`, from here to the end: the device is interrupted and closes its files, then
        # the rest stops, and a second signal cannot cut that short.
        with stop_on_signals() as stop:
            return self._run(stop)

    def _run(self, stop: threading.Event) -> RunResult:
        if self.o.restart:
            supersede_attempts(self.phase_folder)
        self.attempt = next_attempt_folder(self.phase_folder)
        self.frames = RowCounter(self.attempt / "frames.csv")
        self.advisory_rows = RowCounter(self.attempt / ADVISORY_CSV)
        self.record_mocap = self.cfg.runner.record_mocap if self.o.record_mocap is None else self.o.record_mocap
        self._run_json(
            participant=self.o.participant,
            phase=self.o.phase,
            condition=self.condition,
            attempt=self.attempt.name,
            status="running",
            pid=os.getpid(),
            started=utc_now(),
            source=self.source,
            mode=self.mode,
            superseded=False,
            replay_estimates=str(self.o.replay_estimates) if self.o.replay_estimates else None,
        )
        events = CsvLog(self.attempt / EVENTS_CSV, EVENT_COLUMNS)
        watcher = StreamWatcher(load_network_config(), self.attempt, self.device_id, self.estimates_from)
        watcher.start()
        watcher.wait_ready(SUBSCRIBER_READY_S)
        self._event(events, "start", self.attempt.name)
        ended: str | None = None
        self.operator.record = lambda e: self._event(events, e.kind, e.detail, e.time)
        self.operator.start()
        start_error: str | None = None
        try:
            self._audio(events)
            self.supervisor = Supervisor(self.attempt, self.env, self._policy(), lambda part, event, detail: None)
            self._start_children(self.supervisor, stop)
            self._event(events, "device", "started")
            ended = self._wait_for_the_device(self.supervisor, stop, watcher, events)
        except KeyboardInterrupt:  # a signal while starting
            ended = "interrupted"
        except SeesysError as e:
            start_error = str(e)
        if ended == "interrupted":
            self._event(events, "interrupted", "signal received")
        try:
            # The device first (SIGINT: it ends its source and closes its files), then the rest.
            exits = self.supervisor.stop() if self.supervisor is not None else {}
        finally:
            self.operator.restore_terminal()
            watcher.stop()
            if self.output is not None:
                self.output.stop()
        device_rc = exits.get("device")
        device = self.supervisor.parts.get("device") if self.supervisor is not None else None
        status = ended or ("failed" if start_error else "completed" if device_rc == 0 else "failed")
        self.operator.record = None  # events typed from now on belong to no session
        self._event(events, "stop", status)
        events.close()
        frames = self.frames()
        details = {
            "status": status,
            "ended": utc_now(),
            "exit_codes": exits,
            "frames": frames,
            "estimates": watcher.estimates,
            "bad_messages": watcher.bad_messages,
            "watcher_error": watcher.error,
            "device_error": None
            if status in (*DONE_STATUSES, "interrupted") or device is None
            else device.child.last_line(),
            "start_error": start_error,
        }
        if status == "failed" and frames == 0:
            # Nothing was recorded: no attempt of the participant's. The folder is set aside, unnumbered.
            failed = self.attempt
            self.attempt = set_aside_failed_start(failed)
            message = start_error or f"the device failed before its first frame: {details['device_error']}"
            message = message.replace(str(failed), str(self.attempt))
            details.update(failed_start=True, start_error=message, calibration="not calibrated")
            self._run_json(**details)
            raise SeesysError(f"{message} (a failed start, not counted as an attempt; its logs: {self.attempt})")
        details["calibration"] = self._calibrate()
        self._run_json(**details)
        if start_error:
            raise SeesysError(f"{self.attempt}: {start_error}")
        return RunResult(self.attempt, status, frames, watcher.estimates, self.events_logged)

    def _calibrate(self) -> str:
        if (self.attempt / GROUND_TRUTH).exists():
            return "the source's ground truth kept"
        if not (self.cfg.runner.calibrate_at_end and self.record_mocap and (self.attempt / MOCAP_LOG).exists()):
            return "not calibrated"
        rig = self.o.study / CALIBRATION_JSON
        try:
            calibrate_session(
                self.attempt,
                self.cfg.calibration,
                self.cfg.mocap.body,
                marker_camera_from=rig if rig.exists() else None,
                monocular=self.mode == "mono",
            )
        except SeesysError as e:
            return f"failed: {e} (run `seesys study calibrate {self.attempt}` once fixed)"
        return "groundtruth.tum written from the mocap"
