"""The broker ↔ worker messages (DEALER ↔ ROUTER), internal to the service.

Broker → worker: ``[b"F", frame…]`` one or more feature frames, a part each, as the broker decoded and validated them
(:func:`pack_frame`: the worker does not decode them again, and a PSD is inflated once, by the broker, and only for a
model that reads it; a window end's frame is about 37 kB with its PSD, 0.2 kB without) and ``[b"Q"]`` stop. A frame
starts with the f64 token, the broker's monotonic second at which it received the frame, which the worker only hands
back, and the f64 age in ms, how long the frame had been at the broker when it was forwarded. Worker → broker:
``[b"R", json]`` ready (name, pid, model version, whether the model reads the PSD), ``[b"S", json]`` statistics
(every heartbeat) and ``[b"E", (topic, body, meta)…]`` estimates, ``meta`` = f64 token of the window's last frame +
i64 its frame index + u64 its stream session + the estimate's times in the service so far
(:mod:`estimator.service.stages`).

No clock is compared across processes: the worker measures a window's age on its own clock from the moment it
received the last frame, plus the age the broker reported; the broker measures latency on its own clock from the
token it gave. Broker and workers may run on machines whose clocks differ.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from estimator.service import stages
from seesys.core import messages
from seesys.core.device_settings import DeviceSettings
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState
from seesys.core.upper_triangle import symmetric_3x3, upper_triangle

FRAME = b"F"
STOP = b"Q"
READY = b"R"
STATS = b"S"
ESTIMATES = b"E"
_META = struct.Struct("<dqQ")
# token, age (ms), then the frame's stream session, frame index, timestamp, tracking state, frames skipped, RTS schema
# version and fingerprint, and the lengths of what follows: device id (bytes), settings (bytes), RTS row (values),
# PSD (H, W, L; 0 × 0 × 0 without one), then the flags (_HAS_COVARIANCE, _PSD_SKIPPED)
_FRAME_HEAD = struct.Struct("<ddQqdbIHIHBHHHHB")
_HAS_COVARIANCE, _PSD_SKIPPED = 1, 2
_COVARIANCE = struct.Struct("<6d")  # the translation covariance's upper triangle, m²
# fps, ORB features, PSD patch, PSD expansion, near depth, camera normalisation; then the SLAM mode (utf-8)
_SETTINGS = struct.Struct("<HHHHdH")


def pack_frame(token: float, age_ms: float, frame: FeatureFrame) -> bytes:
    """One frame forwarded to a worker, as one part of a ``FRAME`` message (a part per frame: every part costs a
    send and a receive, the bytes cost less)."""
    s = frame.settings
    settings = (
        b""
        if s is None
        else _SETTINGS.pack(
            s.fps, s.orb_features, s.psd_patch_px, s.psd_expansion, s.near_depth, s.camera_normalisation
        )
        + s.slam_mode.encode()
    )
    device = frame.device_id.encode()
    rts = np.ascontiguousarray(frame.rts, dtype="<f4")
    psd = np.ascontiguousarray(frame.psd, dtype=np.uint8) if frame.psd is not None else None
    shape = psd.shape if psd is not None else (0, 0, 0)
    c = frame.translation_covariance
    covariance = _COVARIANCE.pack(*upper_triangle(c)) if c is not None else b""
    head = _FRAME_HEAD.pack(
        token,
        age_ms,
        frame.stream_session,
        frame.frame_index,
        frame.timestamp,
        int(frame.tracking_state),
        frame.frames_skipped,
        frame.rts_schema_version,
        frame.rts_schema_fingerprint,
        len(device),
        len(settings),
        rts.size,
        *shape,
        (_HAS_COVARIANCE if c is not None else 0) | (_PSD_SKIPPED if frame.psd_skipped else 0),
    )
    return b"".join([head, device, settings, rts.data, covariance, psd.data if psd is not None else b""])


def unpack_frames(parts: list[bytes]) -> Iterator[tuple[float, float, FeatureFrame]]:
    """Inverse of :func:`pack_frame` for a whole ``FRAME`` message (``parts`` with ``FRAME`` first): per frame the
    token, the age in ms and the frame (its arrays read-only views of the message)."""
    for part in parts[1:]:
        yield _unpack_frame(part)


def _unpack_frame(data: bytes) -> tuple[float, float, FeatureFrame]:
    (
        token,
        age_ms,
        session,
        index,
        timestamp,
        state,
        skipped,
        version,
        fingerprint,
        device_bytes,
        settings_bytes,
        rts_values,
        h,
        w,
        layers,
        flags,
    ) = _FRAME_HEAD.unpack_from(data)
    at = _FRAME_HEAD.size
    device = data[at : at + device_bytes].decode()
    at += device_bytes
    settings = _settings(data[at : at + settings_bytes])
    at += settings_bytes
    rts = np.frombuffer(data, "<f4", rts_values, at)
    at += 4 * rts_values
    covariance = None
    if flags & _HAS_COVARIANCE:
        covariance = symmetric_3x3(*_COVARIANCE.unpack_from(data, at))
        at += _COVARIANCE.size
    psd = np.frombuffer(data, np.uint8, h * w * layers, at).reshape(h, w, layers) if h else None
    return (
        token,
        age_ms,
        FeatureFrame(
            device,
            index,
            timestamp,
            TrackingState(state),
            rts,
            psd,
            skipped,
            version,
            fingerprint,
            session,
            settings,
            covariance,
            bool(flags & _PSD_SKIPPED),
        ),
    )


@lru_cache(maxsize=1024)
def _settings(data: bytes) -> DeviceSettings | None:
    # A device states the same settings in every frame: each distinct one is built once.
    if not data:
        return None
    fps, features, patch_px, expansion, near_depth, normalisation = _SETTINGS.unpack_from(data)
    return DeviceSettings(
        data[_SETTINGS.size :].decode(), fps, features, patch_px, expansion, near_depth, normalisation
    )


@dataclass(frozen=True)
class ServedEstimate:
    """One estimate as a worker hands it to the broker: its message (``topic``, ``body``) and what the broker checks
    and times it by, the window's last frame's device, token, frame index and stream session and the estimate's times
    in the service so far. A worker process sends it packed (:func:`pack_estimates`); the broker's own worker hands
    it over as it is."""

    topic: bytes
    body: bytes
    device_id: str
    token: float
    frame_index: int
    stream_session: int
    times: stages.WorkerTimes


def pack_estimates(estimates: Iterable[ServedEstimate]) -> list[bytes]:
    """The parts of an ``E`` message after its kind: ``topic, body, meta`` for each estimate."""
    parts: list[bytes] = []
    for e in estimates:
        parts += [e.topic, e.body, _META.pack(e.token, e.frame_index, e.stream_session) + stages.pack(e.times)]
    return parts


def unpack_estimates(parts: list[bytes]) -> Iterator[ServedEstimate]:
    """Inverse of :func:`pack_estimates` (the device id read from each topic); ``struct.error`` for a meta part of
    another length."""
    for k in range(0, len(parts) - 2, 3):
        topic, body, meta = parts[k : k + 3]
        token, frame_index, stream_session = _META.unpack_from(meta)
        device_id = topic[len(messages.ESTIMATE_TOPIC) : -len(messages.TOPIC_END)].decode("utf-8")
        yield ServedEstimate(
            topic, body, device_id, token, frame_index, stream_session, stages.unpack(meta[_META.size :])
        )


def pack_json(data: dict) -> bytes:
    return json.dumps(data, separators=(",", ":")).encode()


def unpack_json(data: bytes) -> dict:
    return json.loads(data)
