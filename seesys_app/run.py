"""``seesys run``: the device, the estimator and the advisory started and supervised as one app.

One run writes one session folder (``--out``, new or empty):

- the device's files (``seesys monitor run --stream --estimates``): ``frames.csv``, ``trajectory.tum``, ``rts.csv``,
  ``psd/``, ``estimates.csv`` (every estimate the device received, with its end-to-end latency) and, from a
  recording with one, ``groundtruth.tum``;
- the advisory's files (generator and player): ``advisory.csv``, ``playback.csv``, ``advisory_events.csv`` and
  the WAV of what the player played (``configs/app.toml`` ``output.wav``; not in the silent condition);
- ``logs/<part>.log``: each child's output (device, estimator, generator, player), and ``logs/estimates.csv``, the
  estimates as the app itself received them (``study.watch``);
- ``app_events.csv``: what the app did and saw (starts, exits, restarts, the stop), one row each, flushed;
- ``configs/``: the configuration every child ran with (the settings in use, with the run's changes, written whole:
  the advisory listens to this device and plays where the audio goes, the device publishes under the id decided
  here, a remote estimator's estimates come from its endpoint);
- at the end ``summary.json`` and the plot (``seesys_app.summary``).

The children are supervised by the session supervisor that ``seesys study run`` and ``seesys advisory run`` use
too (``seesys.io.supervision``), and what the app decides and shows is read from one observation of the run
(``seesys_app.observer``: the session's logs and the estimator's status endpoint). Children start in dependency
order: the estimator (``--local``: ``seesys estimator serve``) until it answers its
status endpoint, the advisory until the generator logs a buffer and the player has started, then the device, so
that no frame is tracked without an estimator or audio. The device is never restarted: its exit ends the run
(``completed`` at the end of a recording, ``failed`` otherwise, with its logs kept). A local estimator, generator
or player that exits is reported in the view and in ``app_events.csv`` and restarted after ``restart_delay_s``,
at most ``max_restarts`` times; the device goes on tracking and logging meanwhile, and estimates resume once the
new estimator has filled a window. Ctrl-C or SIGTERM interrupts the device (it closes its files) and then stops
the rest; every child also dies with the app if the app itself is killed (``seesys.io.processes``).

Audio: the configured output device (``configs/advisory.toml`` ``[audio]``; the default one unless named). With
none (no sound card), or with ``--wav``, the player plays into a private JACK dummy server that the app starts
(``advisory.output``), paced in real time like a sound card, and the WAV is the only output; without ``jackd``
installed that is an error.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from advisory import config as advisory_config
from advisory.conditions import Condition
from advisory.config import AdvisoryConfig, load_advisory_config
from advisory.output import AudioOutput, open_audio_output
from advisory.supervisor import process_args
from estimator.artefact.onnx_model import FOREST_KIND, recorded_training
from estimator.service.config import load_service_config
from seesys.core.errors import SeesysError
from seesys.core.session_layout import ADVISORY_CSV, EVENTS_CSV
from seesys.core.tracking_state import TrackingState
from seesys.io import network as network_config
from seesys.io.children import LOGS, CsvTail, RowCounter
from seesys.io.config import CONFIG_DIR_ENV, ConfigSet
from seesys.io.logfiles import CsvLog
from seesys.io.network import load_network_config
from seesys.io.processes import stop_on_signals
from seesys.io.resources import resolve
from seesys.io.session_files import utc_now
from seesys.io.supervision import PartSpec, SupervisionPolicy, Supervisor
from seesys.io.transport import peer_answers
from seesys_app.config import AppConfig, load_app_config
from seesys_app.information import InformationClock
from seesys_app.observer import Observation, RunObserver
from seesys_app.records import RunRecord, RunState, StreamDrops
from seesys_app.summary import TRACKED_STATES, write_summary
from seesys_app.view import LiveView, ViewSetup
from slam_monitor import monitor_config
from slam_monitor.monitor_config import MonitorConfig, load_monitor_config, resolve_device_id
from slam_monitor.sources import load_camera_config, open_source, parse_source_spec
from study.watch import StreamWatcher

EVENT_COLUMNS = ("wall_time", "part", "event", "detail")
CONFIGS = "configs"
# How long the app waits for its own subscriber sockets before any publisher starts.
SUBSCRIBER_READY_S = 5.0


@dataclass(frozen=True)
class RunOptions:
    """What ``seesys run`` was asked for; None takes the default of ``configs/app.toml``."""

    source: str
    condition: Condition
    out: Path
    local: bool = False
    estimator: str | None = None  # HOST:PORT of a remote service's estimates endpoint
    model: Path | None = None  # a local estimator's ONNX model (default: configs/service.toml)
    wav: bool = False
    mode: str | None = None
    pace: bool | None = None
    max_frames: int | None = None


@dataclass
class RunResult:
    """The session folder, the outcome (completed, interrupted, failed) and ``summary.json``'s content."""

    folder: Path
    status: str
    summary: dict


def estimates_endpoint(host_port: str) -> str:
    """``tcp://HOST:PORT`` from ``HOST:PORT``; SeesysError naming the problem when it is not one."""
    host, sep, port = host_port.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise SeesysError(
            f"--estimator wants HOST:PORT (the service's estimates endpoint, e.g. 192.168.1.20:5556), got {host_port!r}"
        )
    return f"tcp://{host}:{port}"


def check_source(source: str, mode: str) -> None:
    """Open and close the frame source once, so that a bad ``--source`` (unknown kind, missing folder, no depth
    in RGB-D mode) is a SourceError before any part starts. A live camera is only parsed here: the device opens it,
    and holding it twice is what a camera refuses."""
    spec = parse_source_spec(source)
    if spec.kind == "realsense":
        return
    with open_source(spec, load_camera_config(), with_depth=mode == "rgbd"):
        pass


def _new_folder(out: Path) -> Path:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SeesysError(f"{out} exists and is not an empty folder: give a new folder for the session")
    out.mkdir(parents=True, exist_ok=True)
    return out


@dataclass(frozen=True)
class RunPlan:
    """What a run was asked for and what was decided before anything starts: the settings it runs with, the SLAM
    mode and pacing, the device's id and the session folder (made, empty)."""

    options: RunOptions
    cfg: AppConfig
    advisory: AdvisoryConfig
    monitor: MonitorConfig
    mode: str
    pace: bool
    device_id: str
    estimates_endpoint: str | None
    folder: Path


def plan_run(options: RunOptions, cfg: AppConfig | None = None) -> RunPlan:
    """Check the options against the settings and the source, and make the session folder. Raises SeesysError
    (SourceError for the source) naming the problem, before any part starts."""
    if options.local == (options.estimator is not None):
        raise SeesysError("give either --local (start the estimator on this machine) or --estimator HOST:PORT")
    cfg = cfg or load_app_config()
    mode = options.mode or cfg.device.mode
    check_source(options.source, mode)
    monitor = load_monitor_config()
    return RunPlan(
        options,
        cfg,
        load_advisory_config(),
        monitor,
        mode,
        cfg.device.pace if options.pace is None else options.pace,
        # The device's id on the feature stream and the estimator, decided here and given to the device (its
        # configs): the advisory and the app listen to it alone.
        resolve_device_id(monitor.device_id, options.source),
        estimates_endpoint(options.estimator) if options.estimator is not None else None,
        _new_folder(options.out),
    )


class App:
    """One run of ``seesys run`` (see the module docstring), of a :class:`RunPlan`."""

    def __init__(self, plan: RunPlan):
        self.o = plan.options
        self.estimates_endpoint = plan.estimates_endpoint
        self.cfg = plan.cfg
        self.advisory = plan.advisory
        self.mode = plan.mode
        self.pace = plan.pace
        self.monitor = plan.monitor
        self.device_id = plan.device_id
        self.folder = plan.folder
        self.supervisor: Supervisor | None = None  # once the run's settings are written
        self.observer: RunObserver | None = None
        self.output: AudioOutput | None = None  # where the player's audio goes (audible conditions)
        self.audio = "none (silent condition)"
        self.view: LiveView | None = None
        self.watcher: StreamWatcher | None = None  # the app's subscriber to the device's feature stream
        self.config_dir: Path | None = None  # the run's copy of the configs, once written
        self._player_up = False
        self.information = InformationClock(self.advisory.timing.stale_after_s, self.cfg.supervision.first_estimate_s)
        self._inputs_seen = 0  # of the condition's input: estimates, or tracked frames for the motion rules
        self._dropped_at_estimate: dict[str, int] = {}
        self._exits: dict[str, int | None] | None = None  # each child's exit status, once stopped

    # run() shows the view and starts the watcher before any child starts; supervision takes them as given.

    @property
    def _shown_view(self) -> LiveView:
        if self.view is None:
            raise RuntimeError("the live view is used before run() has shown it")
        return self.view

    @property
    def _supervisor(self) -> Supervisor:
        if self.supervisor is None:
            raise RuntimeError("the children are supervised before run() has written the run's settings")
        return self.supervisor

    @property
    def _observer(self) -> RunObserver:
        if self.observer is None:
            raise RuntimeError("the run is observed before run() has started observing it")
        return self.observer

    @property
    def _started_watcher(self) -> StreamWatcher:
        if self.watcher is None:
            raise RuntimeError("the stream watcher is used before run() has started it")
        return self.watcher

    # -- set-up ---------------------------------------------------------------------------------------------------

    def _open_audio(self) -> None:
        """Where the audio goes: the output device, or a JACK dummy server and the WAV (see the module doc)."""
        if not self.o.condition.audible:
            return
        self.output = open_audio_output(self.advisory.audio, dummy=self.o.wav)
        if self.output.unavailable is not None:
            self.event("app", "no audio output", f"{self.output.unavailable}; playing into a WAV instead")
        self.audio = self.output.description if self.output.jack is None else f"WAV only ({self.output.description})"

    def _configure(self) -> dict[str, str]:
        """The run's settings, written whole into the session folder, and the children's environment."""
        self._open_audio()
        timing = replace(self.advisory.timing, listen_to_device=self.device_id)
        audio = self.output.settings(self.advisory.audio) if self.output is not None else self.advisory.audio
        configs = (
            ConfigSet.read()
            .replaced(advisory_config.SECTION, replace(self.advisory, timing=timing, audio=audio))
            .replaced(monitor_config.SECTION, replace(self.monitor, device_id=self.device_id))
        )
        if self.estimates_endpoint is not None:
            network = replace(load_network_config(), estimates_endpoint=self.estimates_endpoint)
            configs = configs.replaced(network_config.SECTION, network)
        self.config_dir = configs.write(self.folder / CONFIGS)
        env = {**os.environ, CONFIG_DIR_ENV: str(self.config_dir)}
        if self.output is not None:
            env.update(self.output.env())
        return env

    def _model_cameras(self) -> str:
        """Which cameras the local estimator's model was trained and fine-tuned on, and how to make it this
        camera's: the user should know when the advisory speaks from a model that never saw their camera."""
        path = self.o.model or resolve(load_service_config(self.config_dir).model)
        recorded = recorded_training(path)
        cameras = recorded.cameras if recorded is not None else None
        forest = recorded is not None and recorded.kind == FOREST_KIND
        trained = "was trained" if forest else "was trained or fine-tuned"
        seen = f"{trained} on the cameras: {', '.join(cameras)}" if cameras else "records no cameras it was trained on"
        if forest:
            # A forest is not fine-tuned: it is trained again, in seconds, with that camera's runs in its data.
            adapt = (
                "train it again with that camera's runs with ground truth in its data: seesys estimator train "
                "--row random_forest, then seesys estimator export (docs/estimator.md)"
            )
        else:
            adapt = (
                "fine-tune it on a few minutes of that camera's sessions with ground truth: seesys estimator "
                "finetune --sessions SESSION... (docs/estimator.md)"
            )
        return f"{Path(path).name} {seen}; for another camera, {adapt}"

    def event(self, part: str, event: str, detail: str = "") -> None:
        """Log an app event and show it, with the parts' state as it is now (a restart shows as done at once)."""
        self.events.write(time.time(), part, event, detail)
        if self.view is not None:
            self.view.note(f"{part}: {event}" + (f" ({detail})" if detail else ""), self._latest(), self._state_now())

    def _latest(self) -> Observation:
        """The newest observation of the run (an empty one before the first look)."""
        return self.observer.latest if self.observer is not None else Observation()

    def _policy(self) -> SupervisionPolicy:
        s = self.cfg.supervision
        return SupervisionPolicy(
            ready_timeout_s=s.ready_timeout_s,
            poll_s=s.status_interval_s,
            restart_delay_s=s.restart_delay_s,
            max_restarts=s.max_restarts,
            stop_timeout_s=s.stop_timeout_s,
            device_stop_timeout_s=s.stop_timeout_s,
        )

    @staticmethod
    def _drops(watcher: StreamWatcher) -> StreamDrops:
        return StreamDrops(watcher.frames_skipped, watcher.losses.lost_in_transit, watcher.bad_messages)

    def _record(self, watcher: StreamWatcher | None) -> RunRecord:
        estimator = self.o.estimator if self.o.estimator is not None else "local"  # HOST:PORT without --local
        return RunRecord(
            self.folder,
            self.o.source,
            self.mode,
            self.pace,
            self.o.condition.value,
            estimator,
            self.audio,
            self.advisory.equation2,
            self.advisory.timing.stale_after_s,
            self.config_dir,
            self.supervisor.statuses() if self.supervisor is not None else {},
            self._drops(watcher) if watcher is not None else None,
            self._latest().estimator.dropped if self.o.local else None,
            self.information.seconds_without,
            dict(self.information.by_reason),
        )

    def _view_setup(self) -> ViewSetup:
        return ViewSetup(
            self.folder,
            self.o.source,
            self.o.condition.value,
            self.cfg.view,
            self.advisory.equation2.beta_m,
            None if self.o.local else self.o.estimator,
        )

    def _new_observer(self) -> RunObserver:
        status_endpoint = load_service_config(self.config_dir).status_endpoint if self.o.local else None
        return RunObserver(self.folder, self.cfg.view, self.device_id, status_endpoint)

    def _refresh(self) -> None:
        """Observe the run and draw it."""
        state = self._state_now()
        self._shown_view.update(self._observer.look(state.parts), state)

    def _estimator_args(self) -> tuple[str, ...]:
        workers = ("--workers", str(self.cfg.local_estimator.workers))
        return ("estimator", "serve", *workers) + (("--model", str(self.o.model)) if self.o.model else ())

    def _advisory_args(self) -> dict[str, tuple[str, ...]]:
        """``seesys advisory generator|player`` arguments (the advisory supervisor's, the player also writing what it
        played to the WAV)."""
        args = process_args(self.o.condition, self.folder)
        if "player" in args:
            args["player"] += ("--capture", str(self.folder / self.cfg.output.wav))
        return args

    def _device_args(self) -> tuple[str, ...]:
        args = (
            "monitor",
            "run",
            "--source",
            self.o.source,
            "--mode",
            self.mode,
            "--out",
            str(self.folder),
            "--estimates",
            "--real-time" if self.pace else "--no-pace",
        )
        return args + (("--max-frames", str(self.o.max_frames)) if self.o.max_frames else ())

    def _player_started(self) -> bool:
        rows = self._advisory_events.new_rows()
        self._player_up = self._player_up or any(
            r["process"].startswith("player[") and r["event"] == "started" for r in rows
        )
        return self._player_up

    def _check_reachable(self, endpoint: str) -> None:
        """A remote estimator (its estimates ``endpoint``) must answer within ``reach_timeout_s``; SeesysError
        otherwise."""
        timeout = self.cfg.supervision.reach_timeout_s
        network = load_network_config(self.config_dir)
        if not peer_answers(endpoint, timeout, network.client_options(network.estimates_endpoint)):
            raise SeesysError(
                f"the estimator at {self.o.estimator} cannot be reached: no ZeroMQ peer answered at "
                f"{endpoint} within {timeout:g} s (is `seesys estimator serve` running "
                f"there, its estimates_endpoint bound on an address this device reaches, and Curve "
                f"set alike on both?)"
            )
        self.event("estimator", "reachable", endpoint)

    def _start_children(self, stop: threading.Event) -> None:
        """The estimator (local) until its status endpoint answers, the advisory until the generator logs a buffer
        and the player has started, then the device; each but the device restarted when it exits."""
        supervisor = self._supervisor
        if self.estimates_endpoint is not None:  # a remote estimator (not --local)
            self._check_reachable(self.estimates_endpoint)
        if self.o.local:
            supervisor.start_ready(
                [
                    PartSpec(
                        "estimator", self._estimator_args(), ready=self._observer.estimator_answers, restartable=True
                    )
                ],
                stop,
                self._refresh,
            )
        generator_rows = RowCounter(self.folder / ADVISORY_CSV)
        self._advisory_events = CsvTail(self.folder / EVENTS_CSV)
        checks: dict[str, Callable[[], bool]] = {
            "generator": lambda: generator_rows() > 0,
            "player": self._player_started,
        }
        supervisor.start_ready(
            [
                PartSpec(name, args, ready=checks[name], restartable=True)
                for name, args in self._advisory_args().items()
            ],
            stop,
            self._refresh,
        )
        supervisor.start(PartSpec("device", self._device_args(), device=True))

    # -- supervision ----------------------------------------------------------------------------------------------

    def _state_now(self) -> RunState:
        drops = self._drops(self.watcher) if self.watcher is not None else StreamDrops()
        parts = self.supervisor.statuses() if self.supervisor is not None else {}
        # Before the first input there is no information, whatever start-up allowance the clock gives the summary:
        # the view must not say "fresh estimates" while the advisory plays its no-information cue.
        lacking = not self._inputs_seen or self.information.lacking(time.monotonic())
        return RunState(parts, drops, self._why_no_information() if lacking else "")

    def _why_no_information(self) -> str:
        """Why no fresh estimate comes, as far as the app can tell: the estimator restarting, windows it refused
        or dropped (every reason by name, counted since the last estimate), the device not tracking, or none
        known (stale; a remote estimator's drops are not known here)."""
        observed = self._latest()
        part = self.supervisor.statuses().get("estimator") if self.supervisor is not None else None
        if part is not None and (
            part.restarting or not part.running or (part.restarts and not observed.estimator.answering)
        ):
            return "estimator restarting"  # exited, or restarted and loading its model
        dropped = observed.estimator.dropped
        if dropped:
            grown = {
                r: n - self._dropped_at_estimate.get(r, 0)
                for r, n in dropped.items()
                if n > self._dropped_at_estimate.get(r, 0)
            }
            if grown:
                return "estimator dropped " + ", ".join(f"{r} {n}" for r, n in grown.items())
        state = observed.tracking_state
        if state in TrackingState.__members__ and state not in TRACKED_STATES:
            return f"tracking {state}"
        if self.o.condition.hears_features:
            return "no tracked frames from the device"
        if not self._inputs_seen:
            return "no estimate yet" + ("" if self.o.local else f" from {self.o.estimator}")
        return "estimates stale" + ("" if self.o.local else f" (remote {self.o.estimator})")

    def _inputs_now(self) -> int:
        """How many inputs of the kind the condition's advisory plays from have arrived: the device's tracked feature
        frames for the motion rules (rotation speed, motion statistic), the estimates otherwise (``none`` logs what
        Equation 2 would have played)."""
        watcher = self._started_watcher
        return watcher.tracked_frames if self.o.condition.hears_features else watcher.estimates

    def _account_information(self) -> None:
        """Advance the information clock with what the device logged and the app received since the last look."""
        now = time.monotonic()
        observed = self._latest()
        if observed.frames > 0:
            self.information.first_frame(now)
        # Only while the device delivers frames: the time after its newest one (it ended, and the app notices at its
        # next look) is not time in which the person moved without information.
        newest_frame = self._started_watcher.last_frame_mono
        if newest_frame is not None:
            now = min(now, newest_frame)
        inputs = self._inputs_now()
        if inputs > self._inputs_seen:
            self.information.advance(now, self._why_no_information())
            self.information.estimate(now)
            self._inputs_seen = inputs
            self._dropped_at_estimate = dict(observed.estimator.dropped or {})
        else:
            self.information.advance(now, self._why_no_information())

    def _supervise_until_stopped(self, stop: threading.Event) -> tuple[str, str | None]:
        """Start the children and supervise them until the device ends or a signal comes; (status, error)."""
        self._start_children(stop)
        supervisor = self._supervisor
        device = supervisor.parts["device"].child
        while not stop.wait(self.cfg.supervision.status_interval_s):
            if not device.running:
                code = device.process.returncode
                self.event("device", "ended", f"status {code}")
                if code == 0:
                    return ("degraded" if self.information.seconds_without > 0 else "completed"), None
                return "failed", f"the device exited with status {code}: {device.last_line()}"
            supervisor.look()
            observation = self._observer.look(supervisor.statuses())
            self._account_information()
            self._shown_view.update(observation, self._state_now())
        self.event("app", "interrupted", "signal received")
        return "interrupted", None

    def _stop(self) -> dict[str, int | None]:
        """Stop every child (once), the watcher and the audio server; the view says so while it waits."""
        if self._exits is None:
            if self.view is not None:
                self.view.stopping("stopping: the device closes its files, then the other parts stop")
            self._exits = self.supervisor.stop() if self.supervisor is not None else {}
            if self.watcher is not None:
                self.watcher.stop()
            if self.output is not None:
                self.output.stop()
        return self._exits

    def run(self) -> RunResult:
        """Run until the device ends, a signal stops it, or a part fails beyond restarting; then stop every child,
        write the summary and return it. SeesysError when the app cannot start."""
        with stop_on_signals() as stop:
            return self._run(stop)

    def _run(self, stop: threading.Event) -> RunResult:
        self.events = CsvLog(self.folder / self.cfg.output.events, EVENT_COLUMNS)
        started = utc_now()
        status, error = "completed", None
        try:
            self.supervisor = Supervisor(self.folder, self._configure(), self._policy(), self.event)
            self.event(
                "app",
                "started",
                f"source {self.o.source}, condition {self.o.condition.value}, "
                f"estimator {'local' if self.o.local else self.o.estimator}, "
                f"audio {self.audio}",
            )
            network = load_network_config(self.config_dir)
            watcher = StreamWatcher(network, self.folder / LOGS, self.device_id)
            (self.folder / LOGS).mkdir(exist_ok=True)
            watcher.start()
            self.watcher = watcher
            watcher.wait_ready(SUBSCRIBER_READY_S)
            self.observer = self._new_observer()
            self.view = LiveView(self._view_setup())
            with self.view.shown():
                camera_warning = load_camera_config(self.config_dir).scale.warning()
                if camera_warning:
                    self.event("app", "camera warning", camera_warning)
                if self.o.local:
                    self.event("app", "model", self._model_cameras())
                try:
                    status, error = self._supervise_until_stopped(stop)
                finally:  # inside the view: it shows the stop until every part has ended
                    self._stop()
        except KeyboardInterrupt:
            status = "interrupted"
            self.event("app", "interrupted", "signal received while starting")
        except SeesysError as e:
            status, error = "failed", str(e)
            self.event("app", "failed", error)
        finally:
            exits = self._stop()
            self.event("app", "stopped", status)
            self.events.close()
        summary = write_summary(
            self._record(self.watcher),
            self.cfg.output,
            status=status,
            error=error,
            started=started,
            ended=utc_now(),
            exits=exits,
        )
        return RunResult(self.folder, status, summary)
