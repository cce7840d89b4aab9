"""The live view of ``seesys run``: what the device, the estimator and the advisory are doing, drawn from what the
app observed (:class:`seesys_app.observer.Observation`: the session's growing logs and the estimator's status) and
the state of its parts and stream (:class:`seesys_app.records.RunState`). The view reads nothing itself.

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

from rich.console import Console, Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from seesys_app.config import ViewConfig
from seesys_app.observer import EstimatorObservation, Observation
from seesys_app.records import RunState

SPARK = "▁▂▃▄▅▆▇█"
PLAIN_INTERVAL_S = 1.0
EVENTS_SHOWN = 3
RUNNING_FOOTER = "Ctrl-C stops"


def sparkline(values: list[float], top: float) -> str:
    """One character per value, from ▁ (0) to █ (``top`` or more)."""
    if not values or top <= 0:
        return ""
    levels = [min(int(v / top * len(SPARK)), len(SPARK) - 1) if math.isfinite(v) and v > 0 else 0 for v in values]
    return "".join(SPARK[level] for level in levels)


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
    return (
        f"{s.elapsed_s:6.1f} s  frames {s.frames} {s.state} {_fps(s)} | estimate {_cm(s.latest_error_m)}"
        f"{age} | information {_information(s)} | pulses {pulses} | e2e {_latency(s)} | drops {_drops(s)} | "
        f"estimator {s.estimator}, {_restarts(s)}"
    )


def panel(s: Snapshot, title: str, footer: str = RUNNING_FOOTER) -> Panel:
    """The view as a rich panel (stdout a terminal); ``footer`` after the elapsed time says how the run ends."""
    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    age = "" if math.isnan(s.estimate_age_s) else f"  ({s.estimate_age_s:.1f} s ago)"
    rows = [
        ("tracking", f"{s.state}  {s.frames} frames  {_fps(s)}"),
        ("estimate", f"{_cm(s.latest_error_m)}{age}  {s.estimates} received"),
        ("information", _information(s)),
        ("pulses", " ".join(map(str, s.pulses)) or "–"),
        ("end to end", _latency(s)),
        ("drops", _drops(s)),
        ("estimator", f"{s.estimator}  {_restarts(s)}"),
        ("last seconds", f"{s.spark}  (top {_cm(s.spark_top_m)})" if s.spark else "–"),
    ]
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
    beta_m: float  # Equation 2's β: the sparkline's least top
    remote_estimator: str | None  # HOST:PORT of a remote service; None: a local one


def estimator_text(estimator: EstimatorObservation, state: RunState, remote: str | None) -> str:
    """The estimator's line: remote, starting, down while it restarts, not answering yet, or up with its model."""
    if remote is not None:
        return f"remote {remote}"
    part = state.parts.get("estimator")
    if part is None:
        return "starting"
    if part.restarting or not part.running:
        return "DOWN (restarting)"
    if not estimator.answering:
        return "starting (not answering yet)"
    return f"up, {estimator.model_version}"


class LiveView:
    """Draws the run (:meth:`update`, from the app's loop, with what it observed and the state of its parts) and the
    app's events (:meth:`note`)."""

    def __init__(self, setup: ViewSetup, console: Console | None = None):
        self.setup = setup
        self.console = console or Console()
        self._title = f"seesys run  {setup.source}  {setup.condition}  → {setup.folder}"
        self.snapshot = Snapshot()
        self._events: deque[str] = deque(maxlen=EVENTS_SHOWN)
        self._last_plain = -math.inf
        self._live: Live | None = None
        self._observation = Observation()
        self._state = RunState()
        self._footer = RUNNING_FOOTER

    def collect(self, observation: Observation | None = None, state: RunState | None = None) -> Snapshot:
        """The snapshot of ``observation`` and ``state`` (each the last given when None)."""
        if observation is not None:
            self._observation = observation
        if state is not None:
            self._state = state
        o, st = self._observation, self._state
        values = list(o.recent_errors_m)
        top = max([self.setup.beta_m, *values])
        drops = st.drops
        local = self.setup.remote_estimator is None
        s = Snapshot(
            elapsed_s=o.elapsed_s,
            frames=o.frames,
            fps=o.fps,
            estimates=o.estimates,
            latest_error_m=o.latest_error_m,
            estimate_age_s=o.estimate_age_s,
            pulses=list(o.pulses),
            latency_ms=o.latency_ms,
            state=o.tracking_state or ("waiting for the device" if "device" not in st.parts else "starting"),
            skipped=drops.skipped_by_device,
            lost=drops.lost_in_transit,
            bad_messages=drops.bad_messages,
            estimator_dropped=o.estimator.dropped if local else None,
            estimator=estimator_text(o.estimator, st, self.setup.remote_estimator),
            restarts={name: part.restarts for name, part in st.parts.items()},
            information=st.information,
            spark=sparkline(values, top),
            spark_top_m=top,
            events=list(self._events),
        )
        self.snapshot = s
        return s

    def note(self, text: str, observation: Observation | None = None, state: RunState | None = None) -> None:
        """An app event: kept for the panel, printed at once in plain mode; ``observation`` and ``state``, the run
        as it is now, redraw the panel with them (an event saying "restarted" beside a state still saying
        "restarting" would contradict it)."""
        self._events.append(f"{time.strftime('%H:%M:%S')} {text}")
        if self._live is None:
            self.console.print(f"[{time.strftime('%H:%M:%S')}] {text}", markup=False, highlight=False)
        else:  # at once: the run may end before the next update
            self.collect(observation, state)
            self.snapshot.events = list(self._events)
            self._live.update(panel(self.snapshot, self._title, self._footer))

    def update(self, observation: Observation | None = None, state: RunState | None = None) -> None:
        snapshot = self.collect(observation, state)
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
        with Live(
            panel(self.collect(), self._title, self._footer),
            console=self.console,
            refresh_per_second=4,
            transient=False,
        ) as live:
            self._live = live
            try:
                yield self
            finally:
                self._live = None
