"""The small records the app hands to its live view and its summary, so that neither needs the ``App`` itself."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from seesys.core.equation2 import Equation2Config
from seesys.io.supervision import PartStatus


@dataclass(frozen=True)
class StreamDrops:
    """What the app's own subscriber to the device's feature stream counted."""

    skipped_by_device: int = 0  # frames the device's monitor could not keep up with
    lost_in_transit: int = 0  # frames that never reached the app
    bad_messages: int = 0


@dataclass(frozen=True)
class RunState:
    """The supervised parts and the stream at one moment, as the app hands them to the live view."""

    parts: dict[str, PartStatus] = field(default_factory=dict)
    drops: StreamDrops = StreamDrops()
    information: str = ""  # why no fresh estimate has come for too long ("" while they come)


@dataclass(frozen=True)
class RunRecord:
    """What ``summary.json`` and the plot say about a finished run, besides what the session's logs hold."""

    folder: Path
    source: str
    mode: str
    paced: bool
    condition: str
    estimator: str  # "local", or the remote service's HOST:PORT
    audio: str
    equation2: Equation2Config
    stale_after_s: float  # the advisory's stale limit: estimates further apart than this are an outage
    config_dir: Path | None  # the run's copy of the configs, once written
    parts: dict[str, PartStatus] = field(default_factory=dict)
    drops: StreamDrops | None = None  # None: the stream was never watched
    estimator_dropped: dict[str, int] | None = None  # what a local estimator last reported dropping, by reason
    # (None: remote, unknown)
    seconds_without_information: float = 0.0  # the device ran, no fresh estimate (seesys_app.information)
    without_information_by_reason: dict[str, float] = field(default_factory=dict)
