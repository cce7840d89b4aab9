"""``seesys advisory run``: start the generator and the player as two processes and keep them running.

The player is left out in the silent ``none`` condition. The audio device is checked before anything starts, so a
missing one is a clear error at once. The processes are supervised by the session supervisor that ``seesys run``
and ``seesys study run`` use too (:mod:`seesys.io.supervision`): a process that exits is logged in
``advisory_events.csv`` and restarted after ``restart_delay_s``, without limit; the other one carries on (the
hand-off reconnects by itself). Only a process that fails with a SEESys error (status 2: configuration, device,
endpoint) the first time it starts stops the run. Their output goes to this command's own.
"""

from __future__ import annotations

import threading
from pathlib import Path

from advisory.audio_device import check_output_device
from advisory.conditions import Condition
from advisory.config import AdvisoryConfig
from advisory.logs import EventLog
from seesys.io.supervision import PartSpec, SupervisionPolicy, Supervisor

_SEESYS_ERROR_EXIT = 2
_STOP_TIMEOUT_S = 5.0


def process_args(condition: Condition, out: Path) -> dict[str, tuple[str, ...]]:
    """The ``seesys`` arguments of each process of a condition."""
    args: dict[str, tuple[str, ...]] = {
        "generator": ("advisory", "generator", "--condition", condition.value, "--out", str(out))
    }
    if condition.audible:
        args["player"] = ("advisory", "player", "--out", str(out))
    return args


def supervise(cfg: AdvisoryConfig, condition: Condition, out: Path, stop: threading.Event) -> None:
    """Run the condition's processes until ``stop`` is set. SeesysError when the audio device is missing or a
    process cannot start."""
    if condition.audible:
        check_output_device(cfg.audio)
    out.mkdir(parents=True, exist_ok=True)
    events = EventLog(out, "supervisor")
    events.event("started", f"condition={condition.value}")
    policy = SupervisionPolicy(
        ready_timeout_s=0.0,
        poll_s=0.2,
        restart_delay_s=cfg.supervisor.restart_delay_s,
        max_restarts=None,
        stop_timeout_s=_STOP_TIMEOUT_S,
        device_stop_timeout_s=_STOP_TIMEOUT_S,
        fatal_status=_SEESYS_ERROR_EXIT,
    )
    supervisor = Supervisor(
        out, None, policy, lambda part, event, detail: events.event(f"{part} {event}", detail), logs=False
    )
    try:
        for name, args in process_args(condition, out).items():
            supervisor.start(PartSpec(name, args, restartable=True))
        while not stop.wait(policy.poll_s):
            supervisor.look()
    finally:
        supervisor.stop()
        events.event("stopped")
        events.close()
