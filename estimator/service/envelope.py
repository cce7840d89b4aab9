"""The broker ↔ worker messages (DEALER ↔ ROUTER), internal to the service.

Broker → worker: ``[b"F", forward, topic, body]`` a feature frame (the body already validated; ``forward`` =
f64 token + f64 age in ms: the token is the broker's monotonic second at which it received the frame, which the
worker only hands back, and the age is how long the frame had been at the broker when it was forwarded) and
``[b"Q"]`` stop. Worker → broker: ``[b"R", json]`` ready (name, pid, model version), ``[b"S", json]`` statistics
(every heartbeat) and ``[b"E", (topic, body, meta)…]`` estimates, ``meta`` = f64 token of the window's last frame
+ i64 its frame index + u64 its stream session + the estimate's times in the service so far
(:mod:`estimator.service.stages`).

No clock is compared across processes: the worker measures a window's age on its own clock from the moment it
received the last frame, plus the age the broker reported; the broker measures latency on its own clock from the
token it gave. Broker and workers may run on machines whose clocks differ.
"""

from __future__ import annotations

import json
import struct

from estimator.service import stages

FRAME = b"F"
STOP = b"Q"
READY = b"R"
STATS = b"S"
ESTIMATES = b"E"
_FORWARD = struct.Struct("<dd")
_META = struct.Struct("<dqQ")


def pack_forward(token: float, age_ms: float) -> bytes:
    return _FORWARD.pack(token, age_ms)


def unpack_forward(data: bytes) -> tuple[float, float]:
    return _FORWARD.unpack(data)


def pack_meta(token: float, frame_index: int, stream_session: int, times: stages.WorkerTimes) -> bytes:
    return _META.pack(token, frame_index, stream_session) + stages.pack(times)


def unpack_meta(data: bytes) -> tuple[float, int, int, stages.WorkerTimes]:
    """Inverse of :func:`pack_meta`; ``struct.error`` for data of another length."""
    token, frame_index, stream_session = _META.unpack_from(data)
    return token, frame_index, stream_session, stages.unpack(data[_META.size:])


def pack_json(data: dict) -> bytes:
    return json.dumps(data, separators=(",", ":")).encode()


def unpack_json(data: bytes) -> dict:
    return json.loads(data)
