"""The broker ↔ worker messages (DEALER ↔ ROUTER), internal to the service.

Broker → worker: ``[b"F", stamp, topic, body]`` a feature frame (``stamp``: f64 wall-clock second at which the
broker received it; the body already validated) and ``[b"Q"]`` stop. Worker → broker: ``[b"R", json]`` ready
(name, pid, model version), ``[b"S", json]`` statistics (every heartbeat) and ``[b"E", (topic, body, meta)…]``
estimates, ``meta`` = f64 stamp of the window's last frame + i64 its frame index.
"""

from __future__ import annotations

import json
import struct

FRAME = b"F"
STOP = b"Q"
READY = b"R"
STATS = b"S"
ESTIMATES = b"E"
_STAMP = struct.Struct("<d")
_META = struct.Struct("<dq")


def pack_stamp(stamp: float) -> bytes:
    return _STAMP.pack(stamp)


def unpack_stamp(data: bytes) -> float:
    return _STAMP.unpack(data)[0]


def pack_meta(stamp: float, frame_index: int) -> bytes:
    return _META.pack(stamp, frame_index)


def unpack_meta(data: bytes) -> tuple[float, int]:
    return _META.unpack(data)


def pack_json(data: dict) -> bytes:
    return json.dumps(data, separators=(",", ":")).encode()


def unpack_json(data: bytes) -> dict:
    return json.loads(data)
