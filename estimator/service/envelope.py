"""The broker ↔ worker messages (DEALER ↔ ROUTER), internal to the service.

Broker → worker: ``[b"F", head, device id, settings, RTS row, PSD shape, PSD cells]`` a feature frame as the
broker decoded and validated it (:func:`pack_frame`: the worker does not decode it again, and the PSD is inflated
once, by the broker; a window end's frame is about 37 kB this way) and ``[b"Q"]`` stop. ``head`` starts with the
f64 token, the broker's monotonic second at which it received the frame, which the worker only hands back, and the
f64 age in ms, how long the frame had been at the broker when it was forwarded. Worker → broker: ``[b"R", json]`` ready (name, pid, model version), ``[b"S", json]`` statistics
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
from functools import lru_cache

import numpy as np

from estimator.service import stages
from seesys.core.device_settings import DeviceSettings
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState

FRAME = b"F"
STOP = b"Q"
READY = b"R"
STATS = b"S"
ESTIMATES = b"E"
_META = struct.Struct("<dqQ")
# token, age (ms), then the frame's stream session, frame index, timestamp, tracking state, frames skipped, RTS schema
# version and fingerprint
_FRAME_HEAD = struct.Struct("<ddQqdbIHI")
# fps, ORB features, PSD patch, PSD expansion, near depth, camera normalisation; then the SLAM mode (utf-8)
_SETTINGS = struct.Struct("<HHHHdH")
_PSD_SHAPE = struct.Struct("<HHH")


def pack_frame(token: float, age_ms: float, frame: FeatureFrame) -> list:
    """The parts of a frame forwarded to a worker (after ``FRAME``); the PSD's cells go as a view, not a copy."""
    s = frame.settings
    settings = b"" if s is None else _SETTINGS.pack(s.fps, s.orb_features, s.psd_patch_px, s.psd_expansion,
                                                     s.near_depth, s.camera_normalisation) + s.slam_mode.encode()
    head = _FRAME_HEAD.pack(token, age_ms, frame.stream_session, frame.frame_index, frame.timestamp,
                            int(frame.tracking_state), frame.frames_skipped, frame.rts_schema_version,
                            frame.rts_schema_fingerprint)
    rts = np.ascontiguousarray(frame.rts, dtype="<f4").data
    if frame.psd is None:
        return [FRAME, head, frame.device_id.encode(), settings, rts, b"", b""]
    psd = np.ascontiguousarray(frame.psd, dtype=np.uint8)
    return [FRAME, head, frame.device_id.encode(), settings, rts, _PSD_SHAPE.pack(*psd.shape), psd.data]


def unpack_frame(parts: list[bytes]) -> tuple[float, float, FeatureFrame]:
    """Inverse of :func:`pack_frame` (``parts`` with ``FRAME`` first): the token, the age in ms and the frame (its
    arrays read-only views of ``parts``)."""
    _, head, device_id, settings, rts, psd_shape, psd = parts
    token, age_ms, session, index, timestamp, state, skipped, version, fingerprint = _FRAME_HEAD.unpack(head)
    cells = None if not psd_shape else np.frombuffer(psd, np.uint8).reshape(_PSD_SHAPE.unpack(psd_shape))
    return token, age_ms, FeatureFrame(device_id.decode(), index, timestamp, TrackingState(state),
                                       np.frombuffer(rts, "<f4"), cells, skipped, version, fingerprint, session,
                                       _settings(settings))


@lru_cache(maxsize=1024)
def _settings(data: bytes) -> DeviceSettings | None:
    # A device states the same settings in every frame: each distinct one is built once.
    if not data:
        return None
    fps, features, patch_px, expansion, near_depth, normalisation = _SETTINGS.unpack_from(data)
    return DeviceSettings(data[_SETTINGS.size:].decode(), fps, features, patch_px, expansion, near_depth,
                          normalisation)


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
