"""The generator → player hand-off: one synthesised buffer per single-part ZeroMQ message.

The generator's PUB socket binds ``handoff.endpoint`` and the player's SUB socket connects with ``ZMQ_CONFLATE``,
which keeps only the newest message (CONFLATE works on single-part messages only, hence one part). PUB never
blocks and drops when no player listens; ZeroMQ reconnects either end after a restart.

Body (little-endian): ``magic "SADV" | u8 version | u8 trigger | u8 N | u8 played N | u32 sample rate |
u64 buffer id | f64 time | f64 play at | f64 arrival | u32 n + n × f32 samples``. Times are on the monotonic clock
(CLOCK_MONOTONIC, shared by the processes of one machine).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from seesys.core.errors import SeesysError

MAGIC = b"SADV"
VERSION = 1
_TRIGGERS = ("tick", "change", "cue")
_HEAD = struct.Struct("<4sBBBBIQdddI")


class HandoffError(SeesysError):
    """A hand-off message is malformed."""


@dataclass(frozen=True)
class AudioBuffer:
    """A buffer for the player, with what the logs need to trace it back to its input."""

    buffer_id: int
    trigger: str
    n_pulses: int  # what the rule gave
    played_pulses: int  # what the buffer holds (0 in the silent condition)
    sample_rate: int
    time: float  # the moment it stands for (tick or arrival of the changing estimate)
    play_at: float  # when its first sample should reach the DAC
    arrival: float  # arrival of the newest input sample it reflects (NaN: none)
    samples: np.ndarray  # float32 mono


def encode_buffer(b: AudioBuffer) -> bytes:
    samples = np.ascontiguousarray(b.samples, dtype="<f4")
    head = _HEAD.pack(
        MAGIC,
        VERSION,
        _TRIGGERS.index(b.trigger),
        b.n_pulses,
        b.played_pulses,
        b.sample_rate,
        b.buffer_id,
        b.time,
        b.play_at,
        b.arrival,
        samples.size,
    )
    return head + samples.tobytes()


def decode_buffer(body: bytes) -> AudioBuffer:
    if len(body) < _HEAD.size:
        raise HandoffError(f"hand-off message of {len(body)} bytes is shorter than its header")
    magic, version, trigger, n, played, rate, buffer_id, t, play_at, arrival, count = _HEAD.unpack_from(body)
    if magic != MAGIC or version != VERSION:
        raise HandoffError(f"not an advisory buffer of version {VERSION} (magic {magic!r}, version {version})")
    if trigger >= len(_TRIGGERS) or len(body) != _HEAD.size + 4 * count:
        raise HandoffError("hand-off message has a bad trigger or a sample count that does not match its length")
    samples = np.frombuffer(body, dtype="<f4", offset=_HEAD.size).astype(np.float32)
    return AudioBuffer(buffer_id, _TRIGGERS[trigger], n, played, rate, t, play_at, arrival, samples)
