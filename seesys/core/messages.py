"""The wire format between device, estimator and advisory: one module, used by both ends.

Every message travels as a two-part ZeroMQ message ``[topic, body]``. The topic is a kind prefix, the device id
and a NUL terminator (``F/<device>\\0`` for features, ``E/<device>\\0`` for estimates): ZeroMQ subscriptions are
prefix matches, and the terminator keeps a subscription to ``dev-1`` from also matching ``dev-10``, while a
subscription to the bare kind prefix still receives every device. Device ids are 1–255 bytes of UTF-8 without
NUL. The body is little-endian binary:

``magic "SEES" | u8 protocol version | u8 kind`` then, in an estimate, ``u8 len + device id (utf-8)`` (a feature
frame's device id is its topic's: the device's most frequent message does not carry it twice), then
``u64 stream session | i64 frame index | f64 timestamp`` followed by the kind's payload:

- :class:`FeatureFrame`: ``u16 RTS schema version | u32 RTS schema fingerprint | u32 frames skipped |
  i8 tracking state | u16 C | u8 B + C × B-byte float RTS row | u8 has_settings`` and, when has_settings, the
  device's settings (:class:`~seesys.core.device_settings.DeviceSettings`: ``u8 SLAM mode | u16 fps |
  u16 ORB features | u16 PSD patch px | u16 PSD expansion | f64 near depth | u16 camera normalisation version``),
  then the frame's predicted translation covariance (below), then ``u8 has_psd`` and, when has_psd, the PSD as
  :func:`pack_stream_psd` writes it. The row travels as float16
  (B = 2) when every value is one (the monitor rounds its values to :func:`stream_resolution`), else as float32
  (B = 4): either way a receiver gets exactly the values sent. "Frames skipped" is the device's running count of
  frames it tracked but did not publish (its monitor fell behind): a receiver that sees a gap in frame indices can
  tell those from frames lost on the way.
- :class:`Estimate`: ``f64 error (m) | f64 server time (ms) | u8 len + model version (utf-8) | u8 K`` and K ×
  ``f32 threshold (m) | f32 probability``: the model's ordinal head, P(error ≥ threshold) for each of its thresholds
  in increasing order (:class:`Exceedance`; K = 0 from a model without a head). Each probability travels with its
  threshold, so a receiver knows what it is for without loading the model (8 bytes per threshold, 24 for
  Equation 2's three classes), and a model of other thresholds is told apart from Equation 2's at once. Then the
  estimated frame's predicted translation covariance, as its feature frame carried it.

A *translation covariance* (3×3, m², the world's axes: the device monitor's Cramér–Rao bound of the frame's pose,
``slam_monitor.observability``) travels as ``u8 B`` (0: none) and, for B = 2 or 4, its upper triangle (xx, xy, xz,
yy, yz, zz) in mm² as six B-byte floats: float16 (three significant digits, :func:`covariance_resolution`) when
every value is within float16's range, else float32. 13 bytes a frame.

The *stream session* is a random number a device draws when it starts streaming and carries in every frame: the
service binds a device id to the stream session that used it first (ZeroMQ tells a subscriber nothing of its
peers), and every estimate carries the stream session of the frames it was made from, so that a device takes only
estimates of its own frames (same device id, same stream session, same frame index).

:func:`decode` validates everything (magic, protocol version, kind, RTS schema, lengths, channel count, shape,
finiteness) and raises :class:`MessageError` naming the problem; a receiver counts and drops such messages, it
never dies on them.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

import numpy as np

from seesys.core import rts_schema
from seesys.core.device_settings import SLAM_MODES, DeviceSettings
from seesys.core.errors import SeesysError
from seesys.core.psd import KEYPOINT_LAYER
from seesys.core.tracking_state import TrackingState
from seesys.core.upper_triangle import symmetric_3x3

# 4: estimates carry the ordinal head's thresholds and probabilities (3 had none). 6: a feature frame's device id
# only in its topic, its RTS row as float16 where it can be, its PSD in the stream's own code (5: the log's code).
# 7: feature frames and estimates carry the frame's predicted translation covariance. 8: a feature frame carries the
# device settings and the covariance only with its PSD (the frames that end a model window, where they are read).
PROTOCOL_VERSION = 8
MAGIC = b"SEES"
#: Topic prefixes of the two kinds; subscribe to one alone to receive every device's messages of that kind.
FEATURE_TOPIC = b"F/"
ESTIMATE_TOPIC = b"E/"
TOPIC_END = b"\x00"

_KIND_FEATURE = 1
_KIND_ESTIMATE = 2
_HEAD = struct.Struct("<4sBB")
_FRAME_ID = struct.Struct("<Qqd")
_PSD_HEAD = struct.Struct("<HHHI")
_ESTIMATE = struct.Struct("<dd")
_EXCEEDANCE = struct.Struct("<ff")
_FEATURE_HEAD = struct.Struct("<HIIbH")
_SETTINGS = struct.Struct("<BHHHHdH")
_PSD_LEVEL = 6
_STREAM_PSD_HEAD = struct.Struct("<HHHBBHHH")
#: Bytes per RTS value on the wire, and their type.
_ROW_TYPES: dict[int, np.dtype] = {2: np.dtype("<f2"), 4: np.dtype("<f4")}
_FLOAT16_MAX = float(np.finfo(np.float16).max)
#: The covariance's six values on the wire (the upper triangle, in mm²) by their width: float16 or float32.
_COVARIANCE_TYPES = {2: struct.Struct("<6e"), 4: struct.Struct("<6f")}


class MessageError(SeesysError):
    """A received message is malformed, of another protocol version, or inconsistent."""


@dataclass(frozen=True)
class FeatureFrame:
    """Device → estimator: the RTS row and (on some frames) the PSD matrix of one tracked frame."""

    device_id: str
    frame_index: int
    timestamp: float
    tracking_state: TrackingState
    rts: np.ndarray
    psd: np.ndarray | None = None
    frames_skipped: int = 0
    rts_schema_version: int = rts_schema.SCHEMA_VERSION
    rts_schema_fingerprint: int = rts_schema.FINGERPRINT
    stream_session: int = 0
    # The device settings and the covariance travel with the PSD only (see :func:`encode`).
    settings: DeviceSettings | None = None  # None: the device states none (the service refuses its windows)
    translation_covariance: np.ndarray | None = None  # 3×3, m², world axes; None: the monitor predicted none
    # The frame carried a PSD that its receiver read past without inflating (``decode(..., psd=False)``, for a
    # model that reads none): ``psd`` is None, yet the frame states settings as any frame with a PSD does.
    psd_skipped: bool = False

    @property
    def states_settings(self) -> bool:
        """Whether the stream states the device settings (and the covariance) on this frame: on a frame with a PSD,
        one that ends a model window (:func:`encode`). A receiver checks settings on these frames only."""
        return self.psd is not None or self.psd_skipped


@dataclass(frozen=True)
class Exceedance:
    """One output of a model's ordinal head: P(error ≥ ``threshold_m``). Both travel as float32: a decoded
    value is the float32 nearest the one sent."""

    threshold_m: float
    probability: float


@dataclass(frozen=True)
class Estimate:
    """Estimator → device and advisories: the estimated pose error of one frame, and the model's ordinal head
    (``head``: one :class:`Exceedance` per threshold, thresholds increasing; empty from a model without a head)."""

    device_id: str
    frame_index: int
    timestamp: float
    error_m: float
    model_version: str
    server_ms: float = math.nan
    stream_session: int = 0  # the stream session of the frames it was made from
    head: tuple[Exceedance, ...] = ()
    translation_covariance: np.ndarray | None = None  # the estimated frame's, as its feature frame carried it


def topic(kind: bytes, device_id: str) -> bytes:
    """The exact topic of ``device_id``'s messages of ``kind`` (:data:`FEATURE_TOPIC` or :data:`ESTIMATE_TOPIC`)."""
    if not device_id or "\x00" in device_id:
        raise ValueError(f"a device id is a non-empty string without NUL, got {device_id!r}")
    return kind + device_id.encode("utf-8") + TOPIC_END


def _pack_text(text: str, what: str) -> bytes:
    data = text.encode("utf-8")
    if len(data) > 255:
        raise ValueError(f"{what} is longer than 255 bytes: {text[:40]!r}...")
    return bytes([len(data)]) + data


def encode(message: FeatureFrame | Estimate) -> list[bytes]:
    """The ``[topic, body]`` frames of ``message``. A feature frame's device settings and translation covariance
    are sent only on a frame with a PSD, a frame that ends a model window, where the service checks the settings and
    copies the covariance to its estimate: on the frames between, 31 of the stream's bytes a frame went to what
    nobody reads (decoded, such a frame has neither)."""
    device = _pack_text(message.device_id, "device id")
    ident = _FRAME_ID.pack(int(message.stream_session), int(message.frame_index), float(message.timestamp))
    if isinstance(message, FeatureFrame):
        rts = np.asarray(message.rts, dtype="<f4")
        if rts.shape != (rts_schema.NUM_CHANNELS,):
            raise ValueError(f"RTS row must have shape ({rts_schema.NUM_CHANNELS},), got {rts.shape}")
        parts = [
            _HEAD.pack(MAGIC, PROTOCOL_VERSION, _KIND_FEATURE),
            ident,
            _FEATURE_HEAD.pack(
                message.rts_schema_version,
                message.rts_schema_fingerprint,
                message.frames_skipped,
                int(message.tracking_state),
                rts.size,
            ),
            _pack_row(rts),
            _pack_settings(message.settings if message.states_settings else None),
            _pack_covariance(message.translation_covariance if message.states_settings else None),
        ]
        if message.psd is None:
            parts.append(b"\x00")
        else:
            parts += [b"\x01", pack_stream_psd(message.psd)]
        return [topic(FEATURE_TOPIC, message.device_id), b"".join(parts)]
    if isinstance(message, Estimate):
        body = b"".join(
            [
                _HEAD.pack(MAGIC, PROTOCOL_VERSION, _KIND_ESTIMATE),
                device,
                ident,
                _ESTIMATE.pack(float(message.error_m), float(message.server_ms)),
                _pack_text(message.model_version, "model version"),
                _pack_head(message.head),
                _pack_covariance(message.translation_covariance),
            ]
        )
        return [topic(ESTIMATE_TOPIC, message.device_id), body]
    raise TypeError(f"cannot encode {type(message).__name__}")


def stream_resolution(rts: np.ndarray) -> np.ndarray:
    """The float32 row ``rts`` at the feature stream's resolution: each value within float16's range rounded to
    the nearest float16 (2^-11 of the value, or 6·10^-8 below 6·10^-5), a larger one left as it is, NaN kept. A row
    at this resolution travels in two bytes a value whenever no value is beyond float16's range."""
    rts = np.asarray(rts, dtype=np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        return np.where(np.abs(rts) <= _FLOAT16_MAX, rts.astype(np.float16).astype(np.float32), rts)


def _pack_row(rts: np.ndarray) -> bytes:
    """``u8 B`` and the row as B-byte floats: float16 when that holds every value exactly."""
    with np.errstate(over="ignore"):
        half = rts.astype("<f2")
    if np.array_equal(half.astype(np.float32), rts, equal_nan=True):
        return b"\x02" + half.tobytes()
    return b"\x04" + rts.tobytes()


def _read_row(r: _Reader, n_channels: int) -> np.ndarray:
    (width,) = r.take(1, "RTS value width")
    dtype = _ROW_TYPES.get(width)
    if dtype is None:
        raise MessageError(f"RTS values of {width} bytes are not a float16 or float32 row")
    return np.frombuffer(r.take(width * n_channels, "RTS row"), dtype=dtype).astype(np.float32)


_MM2_PER_M2 = 1e6


def _wire_covariance(covariance: np.ndarray) -> tuple[int, bytes]:
    """The upper triangle in mm² as it travels: its width (2: float16 where every value fits, else 4: float32) and
    its six values."""
    c = np.asarray(covariance, dtype=np.float64)
    if c.shape != (3, 3):
        raise ValueError(f"a translation covariance is 3×3, got {c.shape}")
    xx, xy, xz, _, yy, yz, _, _, zz = c.ravel().tolist()
    # float32 first (numpy's cast: out of range is ±inf), then float16 from those values, as the wire always rounded;
    # plain floats and struct, not arrays: an estimate's encoding spent two thirds of its time here.
    single = np.array([v * _MM2_PER_M2 for v in (xx, xy, xz, yy, yz, zz)], dtype="<f4")
    values = single.tolist()
    if all(math.isfinite(v) for v in values):
        try:
            return 2, _COVARIANCE_TYPES[2].pack(*values)
        except OverflowError:  # beyond float16's range
            pass
    return 4, single.tobytes()


def _covariance_matrix(values_mm2: tuple[float, ...]) -> np.ndarray:
    # Python floats, not an array: numpy's per-call cost was half of decoding a frame that ends a window.
    return symmetric_3x3(*(v / _MM2_PER_M2 for v in values_mm2))


def covariance_resolution(covariance: np.ndarray) -> np.ndarray:
    """The 3×3 translation covariance ``covariance`` (m²) as a receiver decodes it (see the module docstring)."""
    width, values = _wire_covariance(covariance)
    return _covariance_matrix(_COVARIANCE_TYPES[width].unpack(values))


def _pack_covariance(covariance: np.ndarray | None) -> bytes:
    if covariance is None:
        return b"\x00"
    width, values = _wire_covariance(covariance)
    return bytes([width]) + values


def _read_covariance(r: _Reader) -> np.ndarray | None:
    (width,) = r.take(1, "covariance width")
    if width == 0:
        return None
    layout = _COVARIANCE_TYPES.get(width)
    if layout is None:
        raise MessageError(f"covariance values of {width} bytes are not float16 or float32")
    values = r.unpack(layout, "translation covariance")
    if not all(math.isfinite(v) for v in values) or min(values[0], values[3], values[5]) < 0:
        raise MessageError(f"a translation covariance must be finite with a non-negative diagonal, got {values}")
    return _covariance_matrix(values)


def _pack_head(head: tuple[Exceedance, ...]) -> bytes:
    if len(head) > 255:
        raise ValueError(f"an estimate carries at most 255 head probabilities, got {len(head)}")
    return bytes([len(head)]) + b"".join(_EXCEEDANCE.pack(float(e.threshold_m), float(e.probability)) for e in head)


def _read_head(r: _Reader) -> tuple[Exceedance, ...]:
    (count,) = r.take(1, "head count")
    head = tuple(Exceedance(*r.unpack(_EXCEEDANCE, "head probability")) for _ in range(count))
    thresholds = [e.threshold_m for e in head]
    if not all(math.isfinite(t) and t > 0 for t in thresholds) or thresholds != sorted(set(thresholds)):
        raise MessageError(f"head thresholds must be finite, positive and increasing, got {thresholds}")
    if not all(0.0 <= e.probability <= 1.0 for e in head):  # False for NaN too
        raise MessageError(f"head probabilities must lie in [0, 1], got {[e.probability for e in head]}")
    return head


def _pack_settings(settings: DeviceSettings | None) -> bytes:
    if settings is None:
        return b"\x00"
    return b"\x01" + _SETTINGS.pack(
        SLAM_MODES.index(settings.slam_mode),
        settings.fps,
        settings.orb_features,
        settings.psd_patch_px,
        settings.psd_expansion,
        settings.near_depth,
        settings.camera_normalisation,
    )


def _read_settings(r: _Reader) -> DeviceSettings | None:
    (flag,) = r.take(1, "settings flag")
    if flag == 0:
        return None
    if flag != 1:
        raise MessageError(f"bad settings flag {flag}")
    mode, fps, features, patch_px, expansion, near_depth, normalisation = r.unpack(_SETTINGS, "device settings")
    if mode >= len(SLAM_MODES):
        raise MessageError(f"unknown SLAM mode {mode} in the device settings")
    if not math.isfinite(near_depth):
        raise MessageError(f"near depth is not finite: {near_depth}")
    return DeviceSettings(SLAM_MODES[mode], fps, features, patch_px, expansion, near_depth, normalisation)


class _Reader:
    """Sequential reads from a body that raise MessageError instead of struct.error on truncation."""

    def __init__(self, body: bytes):
        self.body = memoryview(body)
        self.pos = 0

    def take(self, n: int, what: str) -> memoryview:
        if self.pos + n > len(self.body):
            raise MessageError(f"message truncated while reading {what} ({len(self.body)} bytes)")
        view = self.body[self.pos : self.pos + n]
        self.pos += n
        return view

    def unpack(self, fmt: struct.Struct, what: str) -> tuple:
        return fmt.unpack(self.take(fmt.size, what))

    def text(self, what: str) -> str:
        (n,) = self.take(1, what)
        try:
            return bytes(self.take(n, what)).decode("utf-8")
        except UnicodeDecodeError:
            raise MessageError(f"{what} is not valid UTF-8") from None

    def finish(self) -> None:
        if self.pos != len(self.body):
            raise MessageError(f"{len(self.body) - self.pos} unexpected trailing bytes")


def decode(frames: list[bytes], psd: bool = True) -> FeatureFrame | Estimate:
    """Parse and validate a ``[topic, body]`` message; raises :class:`MessageError` on any problem. With ``psd``
    False a feature frame's PSD is read past, its header and lengths checked but its codes not inflated (a
    receiver whose model reads no PSD: inflating one costs ~0.2 ms); the frame says so in ``psd_skipped``."""
    if len(frames) != 2:
        raise MessageError(f"expected 2 message parts (topic, body), got {len(frames)}")
    received_topic, body = bytes(frames[0]), bytes(frames[1])
    r = _Reader(body)
    magic, version, kind = r.unpack(_HEAD, "header")
    if magic != MAGIC:
        raise MessageError(f"not a SEESys message (magic {magic!r})")
    if version != PROTOCOL_VERSION:
        raise MessageError(f"protocol version {version} is not supported (this end speaks {PROTOCOL_VERSION})")
    expected_topic = {_KIND_FEATURE: FEATURE_TOPIC, _KIND_ESTIMATE: ESTIMATE_TOPIC}.get(kind)
    if expected_topic is None:
        raise MessageError(f"unknown message kind {kind}")
    device_id = _topic_device(received_topic, expected_topic) if kind == _KIND_FEATURE else r.text("device id")
    if not device_id or "\x00" in device_id:
        raise MessageError(f"bad device id {device_id!r}")
    stream_session, frame_index, timestamp = r.unpack(_FRAME_ID, "frame id")
    if frame_index < 0:
        raise MessageError(f"negative frame index {frame_index}")
    if not math.isfinite(timestamp):
        raise MessageError(f"timestamp is not finite: {timestamp}")
    if received_topic != topic(expected_topic, device_id):
        raise MessageError(f"topic {received_topic!r} does not match the body (kind {kind}, device {device_id!r})")
    if kind == _KIND_FEATURE:
        return _decode_feature(r, device_id, stream_session, frame_index, timestamp, psd)
    error_m, server_ms = r.unpack(_ESTIMATE, "estimate")
    model_version = r.text("model version")
    head = _read_head(r)
    covariance = _read_covariance(r)
    r.finish()
    if not math.isfinite(error_m) or error_m < 0:
        raise MessageError(f"estimated error must be a finite non-negative number of metres, got {error_m}")
    return Estimate(
        device_id, frame_index, timestamp, error_m, model_version, server_ms, stream_session, head, covariance
    )


def _topic_device(received_topic: bytes, kind: bytes) -> str:
    """The device id of a topic of ``kind`` (the kind prefix, the id, NUL)."""
    if not (received_topic.startswith(kind) and received_topic.endswith(TOPIC_END)):
        raise MessageError(f"topic {received_topic!r} does not match the body (kind {kind!r}: no device id in it)")
    try:
        return received_topic[len(kind) : -len(TOPIC_END)].decode("utf-8")
    except UnicodeDecodeError:
        raise MessageError("device id is not valid UTF-8") from None


def pack_psd(psd: np.ndarray) -> bytes:
    """The compressed form of a PSD matrix (H, W, L) uint8, as carried in a :class:`FeatureFrame` and in the
    session's PSD log: ``u16 H | u16 W | u16 L | u32 n | n bytes zlib(mask + values)``, where, layer by layer
    (L, H, W order), ``mask`` is one bit per cell (set where the cell is non-zero, ``numpy.packbits`` order) and
    ``values`` are the non-zero cells in the same order.

    A PSD is mostly zeros and each layer's values are alike, so splitting where from what and grouping by layer
    compresses better than the raw matrix: a 96×128×3 PSD of the sample (36,864 bytes) takes ~2.45 kB instead of
    ~2.95 kB, which keeps the device's stream under 150 kbit/s at 6 windows/s.
    """
    psd = np.asarray(psd)
    if psd.ndim != 3 or psd.dtype != np.uint8:
        raise ValueError(f"PSD must be (H, W, L) uint8, got {psd.dtype} {psd.shape}")
    planes = np.ascontiguousarray(psd.transpose(2, 0, 1))
    nonzero = planes != 0
    packed = zlib.compress(np.packbits(nonzero).tobytes() + planes[nonzero].tobytes(), _PSD_LEVEL)
    return _PSD_HEAD.pack(*psd.shape, len(packed)) + packed


def _read_psd(r: _Reader) -> np.ndarray:
    h, w, layers, n = r.unpack(_PSD_HEAD, "PSD header")
    packed = bytes(r.take(n, "PSD"))
    cells = h * w * layers
    mask_bytes = (cells + 7) // 8
    inflate = zlib.decompressobj()
    try:
        raw = inflate.decompress(packed, mask_bytes + cells)  # bounded: a small message cannot inflate to GBs
    except zlib.error as e:
        raise MessageError(f"PSD does not decompress: {e}") from None
    if inflate.unconsumed_tail or not inflate.eof or len(raw) < mask_bytes:
        raise MessageError(f"PSD data does not fit its header ({h}x{w}x{layers})")
    # Scattered straight into (H, W, L) order: going through (L, H, W) planes and transposing back took three
    # quarters of a decode, and every frame with a PSD is decoded twice in the service (broker, worker).
    marked = np.flatnonzero(np.unpackbits(np.frombuffer(raw, np.uint8, mask_bytes), count=cells).view(bool))
    values = np.frombuffer(raw, np.uint8, offset=mask_bytes)
    if values.size != marked.size or not values.all():
        raise MessageError(f"PSD holds {values.size} values for {marked.size} marked cells")
    layer, cell = np.divmod(marked, h * w)
    psd = np.zeros(cells, np.uint8)
    psd[cell * layers + layer] = values
    return psd.reshape(h, w, layers)


def _deflate(data: bytes, strategy: int) -> bytes:
    # Raw deflate (no zlib header or checksum: each stream's length is in the message, and TCP checks the bytes).
    compressor = zlib.compressobj(_PSD_LEVEL, zlib.DEFLATED, -15, 9, strategy)
    return compressor.compress(data) + compressor.flush()


def _inflate(data: bytes | memoryview, most: int, what: str) -> bytes:
    """What ``data`` inflates to, at most ``most`` bytes (bounded: a small message cannot inflate to GBs)."""
    inflate = zlib.decompressobj(-15)
    try:
        raw = inflate.decompress(data, most)
    except zlib.error as e:
        raise MessageError(f"PSD {what} do not decompress: {e}") from None
    if inflate.unconsumed_tail:
        raise MessageError(f"PSD {what} are longer than the PSD's cells")
    if not inflate.eof:
        raise MessageError(f"PSD {what} are cut short")
    return raw


def _values(data: bytes | memoryview, count: int, what: str) -> np.ndarray:
    raw = _inflate(data, count, what)
    if len(raw) != count:
        raise MessageError(f"PSD {what}: {len(raw)} for {count} marked cells")
    return np.frombuffer(raw, np.uint8)


def _nested(masks: np.ndarray) -> list[bool]:
    """For each layer after the first, whether its cells all lie among the layer before's (an inlier lies where a
    keypoint does): such a layer's mask is coded over those cells only."""
    return [bool(np.all(masks[layer - 1] | ~masks[layer])) for layer in range(1, len(masks))]


def pack_stream_psd(psd: np.ndarray) -> bytes:
    """The feature stream's code of a PSD matrix (H, W, L) uint8: ``u16 H | u16 W | u16 L | u8 nested |
    u8 constant | u16 a | u16 b | u16 c``, one byte for each constant layer, and three raw deflate streams of a, b
    and c bytes:

    Cells are read row by row, every other row right to left (:func:`_serpentine`).

    - the layers' masks (a bit per cell, set where non-zero; a layer flagged in ``nested``, bit l − 1 for layer l,
      only over the cells of layer l − 1, as inliers lie on keypoints), deflated for runs (``Z_RLE``);
    - the values of the keypoint layer's non-zero cells (mean responses, unlike their neighbours);
    - the other layers' values as differences from the previous non-zero cell's of the layer, modulo 256
      (neighbouring cells of the map layer see surfaces at similar depths), both Huffman-coded only
      (``Z_HUFFMAN_ONLY``: they hold few repeated strings).

    A layer flagged in ``constant`` (bit l), all of whose non-zero cells hold one value (the inlier layer's 255),
    sends that value once, in the byte after the header, instead of its cells' values. Lossless; on the sample a
    PSD takes ~1.9 kB (:func:`pack_psd`, the session log's code, ~2.45 kB).
    """
    psd = np.asarray(psd)
    if psd.ndim != 3 or psd.dtype != np.uint8:
        raise ValueError(f"PSD must be (H, W, L) uint8, got {psd.dtype} {psd.shape}")
    planes = _serpentine(psd.transpose(2, 0, 1))
    masks = planes != 0
    nested = _nested(masks)
    bits = [masks[0].ravel()] + [
        masks[layer][masks[layer - 1]] if nested[layer - 1] else masks[layer].ravel() for layer in range(1, len(masks))
    ]
    values = [planes[layer][masks[layer]] for layer in range(len(planes))]
    constant = [v.size > 0 and bool(np.all(v == v[0])) for v in values]
    plain = [v for layer, v in enumerate(values) if layer == KEYPOINT_LAYER and not constant[layer]]
    differences = [
        np.diff(v, prepend=np.uint8(0))
        for layer, v in enumerate(values)
        if layer != KEYPOINT_LAYER and not constant[layer]
    ]
    streams = [
        _deflate(np.packbits(np.concatenate(bits)).tobytes(), zlib.Z_RLE),
        _deflate(np.concatenate([np.zeros(0, np.uint8), *plain]).tobytes(), zlib.Z_HUFFMAN_ONLY),
        _deflate(np.concatenate([np.zeros(0, np.uint8), *differences]).tobytes(), zlib.Z_HUFFMAN_ONLY),
    ]
    head = _STREAM_PSD_HEAD.pack(*psd.shape, _bits(nested), _bits(constant), *(len(x) for x in streams))
    return head + bytes(int(v[0]) for v, c in zip(values, constant, strict=True) if c) + b"".join(streams)


def _serpentine(planes: np.ndarray) -> np.ndarray:
    """(L, H, W) planes with every other row reversed: read in that order, each cell follows a neighbour, also
    from one row to the next (a few percent fewer bytes for the map layer). Its own inverse."""
    planes = np.array(planes, order="C")
    planes[:, 1::2] = planes[:, 1::2, ::-1]
    return planes


def _bits(flags: list[bool]) -> int:
    return sum(1 << i for i, flag in enumerate(flags) if flag)


def _read_stream_psd_parts(r: _Reader) -> tuple[int, int, int, int, dict[int, int], list[memoryview]]:
    """A stream PSD's header, checked, its constant layers' values and its three code streams (views of the
    message, not inflated)."""
    h, w, layers, nested, constant, *sizes = r.unpack(_STREAM_PSD_HEAD, "PSD header")
    if layers == 0 or layers > 8 or nested >> (layers - 1) or constant >> layers:
        raise MessageError(f"PSD header states {layers} layers, nesting {nested:#x} and constants {constant:#x}")
    constants = dict(
        zip(
            [layer for layer in range(layers) if constant >> layer & 1],
            r.take(constant.bit_count(), "PSD constants"),
            strict=True,
        )
    )
    return h, w, layers, nested, constants, [r.take(n, "PSD") for n in sizes]


def _read_stream_psd(r: _Reader) -> np.ndarray:
    h, w, layers, nested, constants, streams = _read_stream_psd_parts(r)
    cells = h * w
    masks = np.zeros((layers, cells), dtype=bool)
    mask_bits = np.unpackbits(np.frombuffer(_inflate(streams[0], (layers * cells + 7) // 8, "masks"), np.uint8))
    # A nested layer's bits follow its predecessor's marked cells: read layer by layer.
    used = 0
    for layer in range(layers):
        nests = layer and nested >> (layer - 1) & 1
        n = int(np.count_nonzero(masks[layer - 1])) if nests else cells
        if used + n > mask_bits.size:
            raise MessageError(f"PSD masks end before layer {layer}")
        bits = mask_bits[used : used + n].view(bool)
        if nests:
            np.place(masks[layer], masks[layer - 1], bits)
        else:  # a whole layer: a plain copy (indexing it by an all-true mask costs fifty times more)
            masks[layer] = bits
        used += n
    if mask_bits.size != (used + 7) // 8 * 8:
        raise MessageError(f"PSD masks hold {mask_bits.size} bits for {used}")
    counts = [int(n) if layer not in constants else 0 for layer, n in enumerate(masks.sum(axis=1))]
    plain_count = counts[KEYPOINT_LAYER] if layers > KEYPOINT_LAYER else 0
    plain = _values(streams[1], plain_count, "keypoint values")
    differences = _values(streams[2], sum(counts) - plain_count, "values")
    planes = np.zeros((layers, cells), dtype=np.uint8)
    start = 0
    for layer in range(layers):
        if layer in constants:
            values = np.full(int(np.count_nonzero(masks[layer])), constants[layer], np.uint8)
        elif layer == KEYPOINT_LAYER:
            values = plain
        else:
            # Running sums modulo 256 undo the differences (uint8 arithmetic wraps).
            values = np.cumsum(differences[start : start + counts[layer]], dtype=np.uint8)
            start += counts[layer]
        if not values.all():
            raise MessageError(f"PSD layer {layer} holds a zero value in a marked cell")
        np.place(planes[layer], masks[layer], values)
    # Layer by layer into (H, W, L): a fifth of the time of one transposing copy.
    psd = np.empty((h, w, layers), np.uint8)
    for layer, plane in enumerate(_serpentine(planes.reshape(layers, h, w))):
        psd[:, :, layer] = plane
    return psd


def unpack_psd(data: bytes) -> np.ndarray:
    """Inverse of :func:`pack_psd`; raises :class:`MessageError` on malformed data."""
    r = _Reader(data)
    psd = _read_psd(r)
    r.finish()
    return psd


def _decode_feature(
    r: _Reader, device_id: str, stream_session: int, frame_index: int, timestamp: float, inflate_psd: bool
) -> FeatureFrame:
    version, schema_fingerprint, skipped, state_value, n_channels = r.unpack(_FEATURE_HEAD, "feature header")
    try:
        rts_schema.check_compatible(version, schema_fingerprint, f"the feature stream of device {device_id!r}")
    except rts_schema.SchemaMismatch as e:
        raise MessageError(str(e)) from None
    try:
        state = TrackingState(state_value)
    except ValueError:
        raise MessageError(f"unknown tracking state {state_value}") from None
    if n_channels != rts_schema.NUM_CHANNELS:
        raise MessageError(
            f"RTS row has {n_channels} channels, schema v{rts_schema.SCHEMA_VERSION} has {rts_schema.NUM_CHANNELS}"
        )
    rts = _read_row(r, n_channels)
    settings = _read_settings(r)
    covariance = _read_covariance(r)
    (has_psd,) = r.take(1, "PSD flag")
    psd = None
    if has_psd == 1 and inflate_psd:
        psd = _read_stream_psd(r)
    elif has_psd == 1:
        _read_stream_psd_parts(r)  # read past, checked
    elif has_psd != 0:
        raise MessageError(f"bad PSD flag {has_psd}")
    r.finish()
    return FeatureFrame(
        device_id,
        frame_index,
        timestamp,
        state,
        rts,
        psd,
        skipped,
        version,
        schema_fingerprint,
        stream_session,
        settings,
        covariance,
        psd_skipped=has_psd == 1 and not inflate_psd,
    )
