"""One supervised session: the children of ``seesys run``, ``seesys study run``, ``seesys advisory run`` and
``seesys study simulate``.

A :class:`Supervisor` starts ``seesys`` commands as children (:class:`seesys.io.children.Child`) in the order it is
given them, each once the ones before it are ready (a readiness predicate: the child's status endpoint answers, or
a file it writes exists), restarts the restartable ones after they exit (after ``restart_delay_s``, at most
``max_restarts`` times), and stops them all device first: the device gets SIGINT (it ends its source and closes
its files), the others SIGTERM after it, and SIGKILL with their process groups if they do not stop in time.

A part may be a job (``finishes``: a simulated session): its exit with status 0 is the end of its work, never
restarted, and giving up on it is its outcome, returned by :meth:`Supervisor.look`, not the end of the session. A
part with a progress probe (a value that changes while it works: the size of a log it grows) that has not changed
for ``stall_timeout_s`` is hung: it is killed, and that exit counts as a failure.

What happens is reported through ``on_event(part, event, detail)`` (``started``, ``exited``, ``restarted``,
``stalled``), which each caller writes where its users look (the app's ``app_events.csv`` and live view, the
advisory's ``advisory_events.csv``). The state of every part is a :class:`PartStatus`, read from the processes
themselves.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from seesys.core.errors import SeesysError
from seesys.io.children import LOGS, Child

EventSink = Callable[[str, str, str], None]

# What became of a part after an exit (:class:`Exit`).
DONE, RESTARTING, FAILED = "done", "restarting", "failed"


@dataclass(frozen=True)
class PartSpec:
    """A child of the session: its name, the ``seesys`` command's arguments, when it counts as ready (None: once
    started), whether it is restarted when it exits, and whether it is the device (stopped first, by SIGINT).

    ``finishes``: a job, done when it exits with status 0 (see the module docstring). ``progress``: a probe whose
    value changes while the part works (None: not watched for a stall)."""

    name: str
    args: tuple[str, ...]
    ready: Callable[[], bool] | None = None
    restartable: bool = False
    device: bool = False
    finishes: bool = False
    progress: Callable[[], object] | None = None


@dataclass(frozen=True)
class SupervisionPolicy:
    """How a supervisor waits, restarts and stops (seconds).

    ``max_restarts``: None restarts without limit. ``fatal_status``: an exit with this status before the part was
    ever restarted ends the run instead of a restart (a SEESys error of the child, status 2: its configuration,
    device or endpoint will not be different the next time); a job that exits with it fails at once, whichever try
    it was. ``stall_timeout_s``: how long a part with a progress probe may go without progress (None: no limit)."""

    ready_timeout_s: float
    poll_s: float
    restart_delay_s: float
    max_restarts: int | None
    stop_timeout_s: float
    device_stop_timeout_s: float
    fatal_status: int | None = None
    stall_timeout_s: float | None = None


@dataclass(frozen=True)
class Exit:
    """An exit :meth:`Supervisor.look` noticed: the part, its status, whether it was killed as hung, the last line
    of its log, and what became of the part (``done``, ``restarting`` or ``failed``)."""

    name: str
    status: int
    stalled: bool
    last_line: str
    outcome: str


@dataclass(frozen=True)
class PartStatus:
    """One supervised part at one moment."""

    running: bool
    restarting: bool = False  # exited, and a restart is pending
    restarts: int = 0
    exits: tuple[int, ...] = ()


@dataclass
class Part:
    """A started child, how often it was restarted and how it exited."""

    spec: PartSpec
    child: Child
    restarts: int = 0
    restart_at: float | None = None  # monotonic time of a pending restart
    exits: list[int] = field(default_factory=list)
    ended: bool = False  # a job done, or given up
    progress: object = None  # the probe's last value
    progress_at: float = 0.0  # monotonic time it last changed (or the child started)
    stalled: bool = False  # the running child was killed as hung

    @property
    def status(self) -> PartStatus:
        return PartStatus(self.child.running, self.restart_at is not None, self.restarts, tuple(self.exits))


def exit_text(code: int) -> str:
    """``status N``, or the signal that killed the process."""
    return f"killed by {signal.Signals(-code).name}" if code < 0 else f"status {code}"


class Supervisor:
    """The children of one session folder (see the module docstring).

    ``logs``: each child's output goes to ``logs/<name>.log`` in ``folder`` (False: to this process's own output,
    for a supervisor run in a terminal)."""

    def __init__(
        self,
        folder: Path,
        env: Mapping[str, str] | None,
        policy: SupervisionPolicy,
        on_event: EventSink,
        logs: bool = True,
    ):
        self.folder, self.env, self.policy, self.on_event, self.logs = folder, env, policy, on_event, logs
        self.parts: dict[str, Part] = {}

    def start(self, spec: PartSpec) -> Part:
        """Start ``spec`` (again, if it ran before); its ``started`` event names the pid."""
        child = Child.start(
            spec.name, list(spec.args), self.folder, dict(self.env) if self.env else None, log=self.logs
        )
        part = self.parts.get(spec.name)
        if part is None:
            part = self.parts[spec.name] = Part(spec, child)
        else:
            part.child, part.restart_at, part.ended = child, None, False
        part.stalled, part.progress_at = False, time.monotonic()
        part.progress = spec.progress() if spec.progress is not None else None
        self.on_event(spec.name, "started", f"pid {child.process.pid}")
        return part

    def start_ready(
        self, specs: Sequence[PartSpec], stop: threading.Event, waiting: Callable[[], None] = lambda: None
    ) -> None:
        """Start ``specs`` together and wait until each is ready, calling ``waiting`` between looks.

        Raises SeesysError when one exits meanwhile or the time is up, naming it and its log; KeyboardInterrupt
        when ``stop`` is set."""
        for spec in specs:
            self.start(spec)
        ready = {spec.name: spec.ready or (lambda: True) for spec in specs}
        deadline = time.monotonic() + self.policy.ready_timeout_s
        while not all(check() for check in ready.values()):
            for name in ready:
                child = self.parts[name].child
                if not child.running:
                    raise SeesysError(
                        f"the {name} exited while starting ({exit_text(child.process.returncode)}): "
                        f"{child.last_line()} (log: {child.log})"
                    )
            if time.monotonic() > deadline:
                late = [name for name, check in ready.items() if not check()]
                raise SeesysError(
                    f"{' and '.join(late)} not ready after {self.policy.ready_timeout_s:g} s "
                    f"(logs: {self.folder / LOGS})"
                )
            waiting()
            if stop.wait(self.policy.poll_s):
                raise KeyboardInterrupt

    def look(self) -> list[Exit]:
        """Kill the hung parts, notice the restartable parts and jobs that exited, and restart those whose delay
        is over; the exits noticed.

        Raises SeesysError when a part that is not a job exits with the fatal status before any restart, or after
        its last restart."""
        exits = []
        for part in list(self.parts.values()):
            if not part.ended and (part.spec.restartable or part.spec.finishes):
                self._watch_progress(part)
                noticed = self._look_at(part)
                if noticed is not None:
                    exits.append(noticed)
        return exits

    def _watch_progress(self, part: Part) -> None:
        """Kill the part's child when its progress probe has not changed for ``stall_timeout_s``."""
        timeout = self.policy.stall_timeout_s
        if part.spec.progress is None or timeout is None or part.restart_at is not None or not part.child.running:
            return
        now, value = time.monotonic(), part.spec.progress()
        if value != part.progress:
            part.progress, part.progress_at = value, now
        elif now - part.progress_at > timeout:
            part.stalled = True
            self.on_event(part.spec.name, "stalled", f"no progress for {timeout:g} s; killed")
            part.child.kill()

    def _look_at(self, part: Part) -> Exit | None:
        now = time.monotonic()
        if part.restart_at is not None:
            if now >= part.restart_at:
                part.restarts += 1
                self.start(part.spec)
                self.on_event(part.spec.name, "restarted", f"restart {part.restarts}")
            return None
        if part.child.running:
            return None
        code = part.child.process.returncode
        part.exits.append(code)
        how = exit_text(code)
        last = part.child.last_line()
        if part.spec.finishes and code == 0 and not part.stalled:
            self.on_event(part.spec.name, "exited", f"{how}; done")
            return self._end(part, DONE, last)
        if code == self.policy.fatal_status and (not part.restarts or part.spec.finishes):
            self.on_event(part.spec.name, "exited", f"{how}; not restarted")
            return self._give_up(
                part, last, f"the {part.spec.name} could not start ({how}): {last or 'its error is above'}"
            )
        limit = self.policy.max_restarts if part.spec.restartable else 0
        if limit is not None and part.restarts >= limit:
            self.on_event(part.spec.name, "exited", f"{how}; restarted {part.restarts} times already, giving up")
            return self._give_up(
                part,
                last,
                f"the {part.spec.name} exited ({how}) after {part.restarts} restarts: {last} (log: {part.child.log})",
            )
        self.on_event(
            part.spec.name,
            "exited",
            f"{how}{': ' + last if last else ''}; restarting in {self.policy.restart_delay_s:g} s",
        )
        part.restart_at = now + self.policy.restart_delay_s
        return Exit(part.spec.name, code, part.stalled, last, RESTARTING)

    def _end(self, part: Part, outcome: str, last: str) -> Exit:
        part.ended = True
        return Exit(part.spec.name, part.exits[-1], part.stalled, last, outcome)

    def _give_up(self, part: Part, last: str, message: str) -> Exit:
        """A job's failure, returned; any other part's, raised (SeesysError ``message``): it ends the session."""
        if not part.spec.finishes:
            raise SeesysError(message)
        return self._end(part, FAILED, last)

    def running(self, name: str) -> bool:
        return name in self.parts and self.parts[name].child.running

    def statuses(self) -> dict[str, PartStatus]:
        return {name: part.status for name, part in self.parts.items()}

    def stop(self) -> dict[str, int | None]:
        """Stop every part, the device first (SIGINT: it closes its files), then the others, all told at once and
        each given ``stop_timeout_s``; their exit statuses."""
        exits: dict[str, int | None] = {}
        for name, part in self.parts.items():
            if part.spec.device:
                exits[name] = part.child.interrupt(self.policy.device_stop_timeout_s)
        others = {name: part.child for name, part in self.parts.items() if not part.spec.device}
        for child in others.values():
            child.signal(signal.SIGTERM)
        deadline = time.monotonic() + self.policy.stop_timeout_s
        for name, child in others.items():
            exits[name] = child.wait_or_kill(deadline - time.monotonic())
        return exits
