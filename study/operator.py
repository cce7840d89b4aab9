"""The operator's event keys during a session.

On a terminal, single keys: ``i`` tracking initialised (the operator confirms it, as in the paper's procedure),
``o`` the next object reached (1, 2, ...), ``n`` a note (typed, ended by Enter), ``q`` end of the session. From a
pipe or file (scripts, tests), one command per line: ``i``, ``o [k]``, ``n TEXT``, ``q``. Every event carries the
Unix time at which it was read, and is written to ``events.csv`` with it.
"""

from __future__ import annotations

import os
import queue
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TextIO

KEYS_HELP = "keys: i initialised, o object reached, n note, q end"
KINDS = {"i": "initialised", "o": "object", "n": "note", "q": "end"}


@dataclass(frozen=True)
class OperatorEvent:
    kind: str
    detail: str
    time: float = field(default_factory=time.time)  # when it was read: the runner may log it later


def parse_command(line: str, objects_reached: int) -> OperatorEvent | None:
    """One line (or key) as an event; None for an unknown command."""
    key, _, rest = line.strip().partition(" ")
    if key not in KINDS:
        return None
    rest = rest.strip()
    if key == "o":
        return OperatorEvent("object", rest if rest.isdigit() else str(objects_reached + 1))
    return OperatorEvent(KINDS[key], rest)


class OperatorInput(threading.Thread):
    """Reads events from ``stream`` into :attr:`events` (a queue), after handing each to :attr:`record`, until the
    stream ends or ``q`` is read."""

    def __init__(self, stream: TextIO | None = None):
        super().__init__(name="study-operator-input", daemon=True)
        self.stream = stream or sys.stdin
        self.events: queue.Queue[OperatorEvent] = queue.Queue()
        # Called with each event as soon as it is read (the runner logs it there, so an event is on disk even
        # if the runner is killed before it takes the event from the queue).
        self.record: Callable[[OperatorEvent], None] | None = None
        self._objects = 0
        self._terminal: tuple[int, list] | None = None

    def _put(self, text: str) -> bool:
        event = parse_command(text, self._objects)
        if event is None:
            return True
        if event.kind == "object":
            self._objects = int(event.detail)
        if self.record is not None:
            self.record(event)
        self.events.put(event)
        return event.kind != "end"

    def restore_terminal(self) -> None:
        """Give the terminal back its line mode (the thread may still be blocked reading a key)."""
        if self._terminal is not None:
            termios.tcsetattr(self._terminal[0], termios.TCSADRAIN, self._terminal[1])
            self._terminal = None

    def _keys(self, fd: int) -> None:
        self._terminal = (fd, termios.tcgetattr(fd))
        tty.setcbreak(fd)
        try:
            while True:
                key = os.read(fd, 1).decode(errors="ignore")
                if key == "n":
                    note = []
                    while (c := os.read(fd, 1).decode(errors="ignore")) not in ("\n", "\r", ""):
                        note.append(c)
                    key = "n " + "".join(note)
                if not key or not self._put(key):
                    return
        finally:
            self.restore_terminal()

    def run(self) -> None:
        try:
            if self.stream.isatty():
                self._keys(self.stream.fileno())
                return
            for line in self.stream:
                if not self._put(line):
                    return
        except (OSError, ValueError):  # stdin closed under us: no more events
            return
