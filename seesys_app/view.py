"""The live view of ``seesys run``: what the device, the estimator and the advisory are doing, read from the
session's growing logs and the app's own subscriber (``study.watch.StreamWatcher``).

Shown: the device's tracking state, frames and frame rate; the latest estimate and its age; the pulses of the
newest advisory buffers; end-to-end latency percentiles (frame tracked → estimate on the device, from the device's
``estimates.csv``); dropped frames and messages (frames the device's monitor skipped, frames that never reached the
app, malformed messages, and, with a local estimator, what the service dropped or rejected); the estimator's state
and restarts; the estimates of the last seconds as a sparkline; and the newest app events (an estimator that
exited, its restart).

On a terminal the view is a rich panel redrawn in place; when stdout is not a terminal (a pipe, a log file, a
test) it is one plain line per second, and app events are printed as they happen.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console, Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from seesys_app.config import ViewConfig
from seesys_app.records import RunState
from seesys.core.session_layout import ADVISORY_CSV, ESTIMATES_CSV, FRAMES_CSV
from seesys.io.children import CsvTail, RowCounter, last_line

SPARK = "▁▂▃▄▅▆▇█"
# The frame rate is measured over this many seconds of the frame log.
RATE_WINDOW_S = 2.0
PLAIN_INTERVAL_S = 1.0
EVENTS_SHOWN = 3
RUNNING_FOOTER = "Ctrl-C stops"


def sparkline(values: list[float], top: float) -> str:
    """One character per value, from ▁ (0) to █ (``top`` or more)."""
    if not values or top <= 0:
        return ""
    levels = [min(int(v / top * len(SPARK)), len(SPARK) - 1) if math.isfinite(v) and v > 0 else 0 for v in values]
    return "".join(SPARK[level] for level in levels)


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


@dataclass
class Snapshot:
    """What the view shows at one moment."""

    elapsed_s: float = 0.0
    frames: int = 0
    state: str = "starting"
    fps: float = math.nan
    estimates: int = 0
    latest_error_m: float = math.nan
    estimate_age_s: float = math.nan
    pulses: list[int] = field(default_factory=list)
    latency_ms: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # p50, p95, p99
    skipped: int = 0  # frames the device's monitor could not keep up with
    lost: int = 0  # frames that never reached the app
    bad_messages: int = 0
    estimator_dropped: dict[str, int] | None = None  # by reason; None: unknown (remote or not answering)
    estimator: str = "–"
    restarts: dict[str, int] = field(default_factory=dict)
    information: str = ""  # why there is no fresh estimate now ("" while there is one)
    spark: str = ""
    spark_top_m: float = math.nan
    events: list[str] = field(default_factory=list)


def _cm(error_m: float) -> str:
    return "–" if math.isnan(error_m) else f"{error_m * 100:.2f} cm"


def _fps(s: Snapshot) -> str:
    # No rate yet (fewer than two looks at the frame log): a dash, never "nan".
    return "– fps" if math.isnan(s.fps) else f"{s.fps:.1f} fps"


def _latency(s: Snapshot) -> str:
    p50, p95, p99 = s.latency_ms
    return "–" if math.isnan(p50) else f"p50 {p50:.0f} / p95 {p95:.0f} / p99 {p99:.0f} ms"


def dropped_text(dropped: dict[str, int] | None) -> str:
    """What the estimator dropped or rejected, every reason by name ("?": unknown, "0": nothing)."""
    if dropped is None:
        return "?"
    return ", ".join(f"{reason} {n}" for reason, n in dropped.items() if n) or "0"


def _information(s: Snapshot) -> str:
    return f"NONE: {s.information}" if s.information else "fresh estimates"


def _drops(s: Snapshot) -> str:
    estimator = dropped_text(s.estimator_dropped)
    return f"skipped {s.skipped}, lost {s.lost}, bad {s.bad_messages}, estimator {estimator}"


def _restarts(s: Snapshot) -> str:
    done = {name: n for name, n in s.restarts.items() if n}
    return ", ".join(f"{name} restarted {n}×" for name, n in done.items()) or "no restarts"


def plain_line(s: Snapshot) -> str:
    """The view as one line (stdout not a terminal)."""
    age = "" if math.isnan(s.estimate_age_s) else f" ({s.estimate_age_s:.1f} s ago)"
    pulses = " ".join(map(str, s.pulses)) or "–"
    return (f"{s.elapsed_s:6.1f} s  frames {s.frames} {s.state} {_fps(s)} | estimate {_cm(s.latest_error_m)}"
            f"{age} | information {_information(s)} | pulses {pulses} | e2e {_latency(s)} | drops {_drops(s)} | estimator {s.estimator}, "
            f"{_restarts(s)}")


def panel(s: Snapshot, title: str, footer: str = RUNNING_FOOTER) -> Panel:
    """The view as a rich panel (stdout a terminal); ``footer`` after the elapsed time says how the run ends."""
    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    age = "" if math.isnan(s.estimate_age_s) else f"  ({s.estimate_age_s:.1f} s ago)"
    rows = [("tracking", f"{s.state}  {s.frames} frames  {_fps(s)}"),
            ("estimate", f"{_cm(s.latest_error_m)}{age}  {s.estimates} received"),
            ("information", _information(s)),
            ("pulses", " ".join(map(str, s.pulses)) or "–"),
            ("end to end", _latency(s)),
            ("drops", _drops(s)),
            ("estimator", f"{s.estimator}  {_restarts(s)}"),
            ("last seconds", f"{s.spark}  (top {_cm(s.spark_top_m)})" if s.spark else "–")]
    for name, value in rows:
        table.add_row(name, value)
    events = Text("\n".join(s.events), style="yellow") if s.events else Text("")
    return Panel(Group(table, events), title=title, subtitle=f"{s.elapsed_s:.0f} s  {footer}")


@dataclass(frozen=True)
class ViewSetup:
    """What the view is told once, when the run starts."""

    folder: Path
    source: str
    condition: str
    config: ViewConfig
    device_id: str  # the device whose drops the local estimator reports
    beta_m: float  # Equation 2's β: the sparkline's least top
    remote_estimator: str | None  # HOST:PORT of a remote service; None: a local one, asked at status_endpoint
    status_endpoint: str | None


class LiveView:
    """Reads the session's logs into a :class:`Snapshot` and shows it; the app calls :meth:`update` from its loop
    with the state of its parts."""

    def __init__(self, setup: ViewSetup, console: Console | None = None):
        self.setup = setup
        self.console = console or Console()
        self.cfg = setup.config
        folder = setup.folder
        self._title = f"seesys run  {setup.source}  {setup.condition}  → {folder}"
        self._folder = folder
        self._frames = RowCounter(folder / FRAMES_CSV)
        self._rates: deque[tuple[float, int]] = deque()
        self._estimates = CsvTail(folder / ESTIMATES_CSV)
        self._recent: deque[tuple[float, float]] = deque()  # (received unix, error m)
        self._latencies: deque[float] = deque(maxlen=self.cfg.latency_window)
        self._advisory = CsvTail(folder / ADVISORY_CSV)
        self._pulses: deque[int] = deque(maxlen=self.cfg.buffers_shown)
        self.snapshot = Snapshot()
        self._events: deque[str] = deque(maxlen=EVENTS_SHOWN)
        self._started = time.monotonic()
        self._last_plain = -math.inf
        self._last_status = -math.inf
        self._status: dict | None = None
        self._live: Live | None = None
        self._state = RunState()
        self._footer = RUNNING_FOOTER

    # -- the estimator's status (local estimator only) -----------------------------------------------------------

    def estimator_answers(self) -> bool:
        """Ask the local estimator for its status now; True when it answered."""
        from estimator.service.broker import ServiceError
        from estimator.service.status import query_status

        endpoint = self.setup.status_endpoint
        if endpoint is None:
            raise RuntimeError("only a local estimator is asked for its status (a remote one has no endpoint here)")
        self._last_status = time.monotonic()
        try:
            self._status = query_status(endpoint, self.cfg.status_timeout_ms)
        except ServiceError:
            self._status = None
        return self._status is not None

    def _estimator_state(self) -> tuple[str, dict[str, int] | None]:
        if self.setup.remote_estimator is not None:
            return f"remote {self.setup.remote_estimator}", None
        part = self._state.parts.get("estimator")
        if part is None:
            return "starting", None
        if part.restarting or not part.running:
            return "DOWN (restarting)", None
        if time.monotonic() - self._last_status >= self.cfg.estimator_poll_s:
            self.estimator_answers()
        if self._status is None:
            return "starting (not answering yet)", None
        device = self._status["devices"].get(self.setup.device_id)
        dropped = dict(device["dropped"]) if device else {}
        for reason, n in self._status["rejected"].items():  # messages the broker rejected, by their own reasons
            dropped[f"rejected {reason}"] = n
        return f"up, {self._status['model_version']}", dropped

    # -- reading the logs ----------------------------------------------------------------------------------------

    def collect(self, state: RunState | None = None) -> Snapshot:
        """The snapshot of now; ``state``: the app's parts and stream as they are now (the last given when None)."""
        if state is not None:
            self._state = state
        now_mono, now = time.monotonic(), time.time()
        s = Snapshot(elapsed_s=now_mono - self._started)
        s.frames = self._frames()
        row = last_line(self._folder / FRAMES_CSV).split(",")
        s.state = row[2] if len(row) > 2 else ("waiting for the device" if "device" not in self._state.parts
                                               else "starting")
        self._rates.append((now_mono, s.frames))
        while len(self._rates) > 2 and now_mono - self._rates[0][0] > RATE_WINDOW_S:
            self._rates.popleft()
        (t0, f0), (t1, f1) = self._rates[0], self._rates[-1]
        s.fps = (f1 - f0) / (t1 - t0) if t1 > t0 else math.nan
        for r in self._estimates.new_rows():
            self._recent.append((_float(r["received_unix"]), _float(r["error_m"])))
            latency = _float(r["end_to_end_ms"])
            if not math.isnan(latency):
                self._latencies.append(latency)
            self.snapshot.estimates += 1
        s.estimates = self.snapshot.estimates
        if self._recent:
            received, s.latest_error_m = self._recent[-1]
            s.estimate_age_s = now - received
        while self._recent and now - self._recent[0][0] > self.cfg.sparkline_s:
            self._recent.popleft()
        values = [error for _, error in self._recent]
        s.spark_top_m = max([self.setup.beta_m, *values])
        s.spark = sparkline(values, s.spark_top_m)
        if self._latencies:
            p50, p95, p99 = (float(v) for v in np.percentile(list(self._latencies), [50, 95, 99]))
            s.latency_ms = (p50, p95, p99)
        for r in self._advisory.new_rows():
            self._pulses.append(int(r["played_pulses"]) if r["played_pulses"].isdigit() else 0)
        s.pulses = list(self._pulses)
        drops = self._state.drops
        s.skipped, s.lost, s.bad_messages = drops.skipped_by_device, drops.lost_in_transit, drops.bad_messages
        s.estimator, s.estimator_dropped = self._estimator_state()
        s.restarts = {name: part.restarts for name, part in self._state.parts.items()}
        s.information = self._state.information
        s.events = list(self._events)
        self.snapshot = s
        return s

    def note(self, text: str, state: RunState | None = None) -> None:
        """An app event: kept for the panel, printed at once in plain mode; ``state``, the parts as they are now,
        redraws the panel with them (an event saying "restarted" beside a state still saying "restarting" would
        contradict it)."""
        self._events.append(f"{time.strftime('%H:%M:%S')} {text}")
        if self._live is None:
            self.console.print(f"[{time.strftime('%H:%M:%S')}] {text}", markup=False, highlight=False)
        else:  # at once: the run may end before the next update
            if state is not None:
                self.collect(state)
            self.snapshot.events = list(self._events)
            self._live.update(panel(self.snapshot, self._title, self._footer))

    def update(self, state: RunState | None = None) -> None:
        snapshot = self.collect(state)
        if self._live is not None:
            self._live.update(panel(snapshot, self._title, self._footer))
        elif time.monotonic() - self._last_plain >= PLAIN_INTERVAL_S:
            self._last_plain = time.monotonic()
            self.console.print(plain_line(snapshot), markup=False, highlight=False, soft_wrap=True)

    def stopping(self, what: str) -> None:
        """The run is stopping (``what``: why and what it waits for): the panel's footer says so instead of how to
        stop it, and a plain view prints it."""
        self._footer = what
        if self._live is not None:
            self._live.update(panel(self.snapshot, self._title, self._footer))
        else:
            self.console.print(what, markup=False, highlight=False)

    @contextlib.contextmanager
    def shown(self) -> Iterator[LiveView]:
        """The panel on a terminal (redrawn by :meth:`update`), plain lines otherwise."""
        if not self.console.is_terminal:
            yield self
            return
        with Live(panel(self.collect(), self._title, self._footer), console=self.console, refresh_per_second=4,
                  transient=False) as live:
            self._live = live
            try:
                yield self
            finally:
                self._live = None
