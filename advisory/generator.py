"""The receiver/generator process (paper §7.2, process a).

It subscribes to the condition's input (estimates, or the device's features), keeps the moving average, and every
1/3 s (and at once when a new input changes N, see ``advisory.scheduler``) synthesises a buffer and publishes it
to the player over the hand-off socket. It never waits on the player: PUB drops when nobody listens. Every buffer
is logged to ``advisory.csv`` with the rule that gave its pulse count (``pulses_from``: the model's ordinal head or
Equation 2 of the moving-mean estimate, see ``advisory.scheduler``); status changes and bad messages to
``advisory_events.csv``.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import zmq

from advisory.advice import Advice, Buffer
from advisory.conditions import Condition, ConditionInput, condition_input
from advisory.config import AdvisoryConfig
from advisory.handoff import AudioBuffer, encode_buffer
from advisory.logs import EventLog
from advisory.scheduler import CUE
from advisory.synth import synthesise, synthesise_cue
from seesys.core.messages import MessageError, decode
from seesys.core.session_layout import ADVISORY_COLUMNS, ADVISORY_CSV
from seesys.io.logfiles import CsvLog
from seesys.io.network import NetworkConfig
from seesys.io.transport import publisher, subscriber

# Bad messages: the first few are logged one by one, then one line per this many, so a broken sender cannot
# flood the log.
_BAD_MESSAGE_LOG_EVERY = 100
_BAD_MESSAGES_LOGGED_IN_FULL = 10


class Generator:
    """One generator: sockets, scheduler and logs for a condition, run until ``stop`` is set."""

    def __init__(self, cfg: AdvisoryConfig, network: NetworkConfig, condition: Condition, out: Path):
        self._cfg = cfg
        self._condition = condition
        self._input: ConditionInput = condition_input(condition, cfg, network)
        self._events = EventLog(out, "generator")
        self._log = CsvLog(out / ADVISORY_CSV, ADVISORY_COLUMNS)
        self._ctx = zmq.Context()
        self._pub = publisher(self._ctx, cfg.handoff.endpoint, "advisory hand-off", cfg.handoff.send_high_water_mark)
        self._sub = subscriber(
            self._ctx,
            self._input.endpoint,
            f"{condition.value} input",
            [self._input.topic],
            options=network.client_options(self._input.endpoint),
        )
        self._advice = Advice(condition, cfg, time.monotonic(), cfg.audio.schedule_latency_s)
        self._status = self._advice.scheduler.status
        self._buffers: dict[int, np.ndarray] = {}
        self._bad_messages = 0
        self._cue = synthesise_cue(cfg.no_information, cfg.audio.sample_rate, cfg.timing.buffer_s)
        self._events.event(
            "started", f"condition={condition.value} input={self._input.endpoint} handoff={cfg.handoff.endpoint}"
        )

    def _samples(self, n: int) -> np.ndarray:
        if n not in self._buffers:
            self._buffers[n] = synthesise(n, self._cfg.equation2, self._cfg.audio, self._cfg.timing.buffer_s)
        return self._buffers[n]

    def _emit(self, buffer: Buffer) -> None:
        d = buffer.decision
        samples = self._cue if buffer.trigger == CUE else self._samples(buffer.played)
        self._pub.send(
            encode_buffer(
                AudioBuffer(
                    buffer.buffer_id,
                    buffer.trigger,
                    d.n_pulses,
                    buffer.played,
                    self._cfg.audio.sample_rate,
                    d.time,
                    buffer.play_at,
                    d.arrival,
                    samples,
                )
            )
        )
        self._log.write(*buffer.row(time.time(), self._condition))

    def _note_status(self) -> None:
        status = self._advice.scheduler.status
        if status != self._status:
            self._events.event(
                "input " + status, f"{self._status} -> {status} (stale after {self._cfg.timing.stale_after_s} s)"
            )
            self._status = status

    def _bad_message(self, error: MessageError) -> None:
        self._bad_messages += 1
        n = self._bad_messages
        if n <= _BAD_MESSAGES_LOGGED_IN_FULL or n % _BAD_MESSAGE_LOG_EVERY == 0:
            self._events.event("bad message", f"#{n}: {error}")

    def _receive(self) -> None:
        """Take every message waiting on the input socket."""
        while True:
            try:
                frames = self._sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            arrival = time.monotonic()
            try:
                message = decode(frames)
            except MessageError as e:
                self._bad_message(e)
                continue
            reading = self._input.sample(message)
            if reading is None:
                continue
            for buffer in self._advice.take(arrival, reading):
                self._emit(buffer)
            self._note_status()

    def run(self, stop: threading.Event) -> None:
        poll_s = self._cfg.handoff.poll_ms / 1000.0
        try:
            while not stop.is_set():
                wait = min(max(self._advice.scheduler.next_tick - time.monotonic(), 0.0), poll_s)
                if self._sub.poll(int(math.ceil(wait * 1000))):
                    self._receive()
                now = time.monotonic()
                if now >= self._advice.scheduler.next_tick:
                    self._emit(self._advice.tick(now))
                    self._note_status()
        finally:
            self._events.event("stopped", f"{self._advice.buffers} buffers, {self._bad_messages} bad messages")
            self._close()

    def _close(self) -> None:
        self._sub.close()
        self._pub.close()
        self._ctx.term()
        self._log.close()
        self._events.close()
