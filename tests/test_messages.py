import dataclasses
import math
import struct
import zlib

import numpy as np
import pytest

from seesys.core import messages, rts_schema
from seesys.core.messages import Estimate, FeatureFrame, MessageError, decode, encode
from seesys.core.tracking_state import TrackingState


def feature(psd=None):
    rts = np.arange(rts_schema.NUM_CHANNELS, dtype=np.float32) * 0.5
    return FeatureFrame("dev-1", 42, 1000.5, TrackingState.OK, rts, psd)


def test_feature_round_trip_with_and_without_psd():
    psd = np.zeros((96, 128, 3), np.uint8)
    psd[10:20, 30:40, 1] = 255
    for msg in (feature(), feature(psd)):
        out = decode(encode(msg))
        assert out.device_id == "dev-1" and out.frame_index == 42 and out.timestamp == 1000.5
        assert out.tracking_state is TrackingState.OK
        np.testing.assert_array_equal(out.rts, msg.rts)
        if msg.psd is None:
            assert out.psd is None
        else:
            np.testing.assert_array_equal(out.psd, psd)


def test_a_receiver_whose_model_reads_no_psd_reads_past_it_and_still_gets_the_settings():
    from seesys.core.device_settings import DeviceSettings

    psd = np.zeros((96, 128, 3), np.uint8)
    psd[10:20, 30:40, 1] = 255
    settings = DeviceSettings("rgbd", 30, 1000, 8, 2, 0.5, 1)
    covariance = np.diag([4e-6, 2e-6, 9e-6])
    sent = dataclasses.replace(feature(psd), settings=settings, translation_covariance=covariance)
    full, skipped = decode(encode(sent)), decode(encode(sent), psd=False)
    assert skipped.psd is None and skipped.psd_skipped and not full.psd_skipped
    assert skipped.states_settings and skipped.settings == full.settings == settings
    np.testing.assert_array_equal(skipped.translation_covariance, full.translation_covariance)
    np.testing.assert_array_equal(skipped.rts, full.rts)
    plain = decode(encode(feature()), psd=False)  # a frame without a PSD is as it was
    assert plain.psd is None and not plain.psd_skipped and not plain.states_settings
    # Read past, a PSD's framing is still checked: a header stating no layer, or codes cut short, are refused.
    topic, body = encode(sent)
    head = struct.Struct("<HHHBBHHH")
    at = len(body) - len(messages.pack_stream_psd(psd))
    h, w, _, *rest = head.unpack_from(body, at)
    no_layers = body[:at] + head.pack(h, w, 0, *rest) + body[at + head.size :]
    for bad, message in ((no_layers, "PSD header states 0 layers"), (body[:-3], "PSD")):
        with pytest.raises(MessageError, match=message):
            decode([topic, bad], psd=False)


def test_estimate_round_trip_and_topic():
    msg = Estimate("dev-1", 7, 12.25, 0.0061, "deepsee-1", 3.5)
    topic, body = encode(msg)
    assert topic == b"E/dev-1\x00"
    assert decode([topic, body]) == msg


def test_mostly_zero_psd_compresses():
    psd = np.zeros((96, 128, 3), np.uint8)
    psd[24:72:3, 32:96:3, 0] = 40
    _, body = encode(feature(psd))
    assert len(body) < psd.nbytes / 10


@pytest.mark.parametrize(
    "mangle, message",
    [
        (lambda t, b: [t, b[:-3]], "truncated"),
        (lambda t, b: [t, b + b"x"], "trailing"),
        (lambda t, b: [t, b"JUNK" + b[4:]], "magic"),
        (lambda t, b: [t, b[:4] + bytes([99]) + b[5:]], "protocol version 99"),
        (lambda t, b: [t, b[:5] + bytes([7]) + b[6:]], "unknown message kind"),
        (lambda t, b: [b"E/dev-1\x00", b], "does not match"),
        (lambda t, b: [b"F/dev-1", b], "does not match"),
        (lambda t, b: [t], "expected 2 message parts"),
    ],
)
def test_malformed_messages_raise_message_error(mangle, message):
    topic, body = encode(feature())
    with pytest.raises(MessageError, match=message):
        decode(mangle(topic, body))


def test_wrong_channel_count_and_bad_values_are_rejected():
    topic, body = encode(feature())
    head = 4 + 1 + 1 + 8 + 16 + 2 + 4 + 4  # a feature frame's body holds no device id: its topic does
    wrong = body[:head] + struct.pack("<bH", 2, 3) + body[head + 3 :]
    with pytest.raises(MessageError, match="channels"):
        decode([topic, wrong])
    bad_state = body[:head] + struct.pack("<b", 9) + body[head + 1 :]
    with pytest.raises(MessageError, match="tracking state"):
        decode([topic, bad_state])
    t, b = encode(Estimate("d", 1, 1.0, 0.01, "m"))
    with pytest.raises(MessageError, match="non-negative"):
        decode([t, b.replace(struct.pack("<d", 0.01), struct.pack("<d", -1.0))])
    with pytest.raises(MessageError, match="not finite"):
        decode([t, b.replace(struct.pack("<d", 1.0), struct.pack("<d", math.nan))])


def test_psd_that_lies_about_its_shape_is_rejected():
    psd = np.ones((4, 4, 3), np.uint8)
    topic, body = encode(feature(psd))
    i = body.index(struct.pack("<HHH", 4, 4, 3))
    lying = body[:i] + struct.pack("<HHH", 5, 4, 3) + body[i + 6 :]
    with pytest.raises(MessageError, match="PSD"):
        decode([topic, lying])


def test_frames_of_another_rts_schema_are_refused_by_name():
    frame = feature()
    for other in (
        dataclasses.replace(frame, rts_schema_version=rts_schema.SCHEMA_VERSION + 1),
        dataclasses.replace(frame, rts_schema_fingerprint=rts_schema.FINGERPRINT ^ 1),
    ):
        with pytest.raises(MessageError, match=f"device 'dev-1' uses RTS schema v{other.rts_schema_version}"):
            decode(encode(other))
    out = decode(encode(dataclasses.replace(frame, frames_skipped=12)))
    assert (out.frames_skipped, out.rts_schema_version, out.rts_schema_fingerprint) == (
        12,
        rts_schema.SCHEMA_VERSION,
        rts_schema.FINGERPRINT,
    )


@pytest.mark.parametrize("version", [1, 2, 3, 5, 6, 7])
@pytest.mark.parametrize("kind", ["feature", "estimate"])
def test_a_message_of_an_earlier_protocol_version_is_refused(version, kind):
    """Version 2 had no stream session and no device settings, version 3 no head probabilities in an estimate,
    version 5 a device id in a feature frame's body and its RTS row in float32, version 6 no covariance, version 7
    the settings and the covariance on every frame: refused naming both versions, never misread."""
    topic, body = encode(feature() if kind == "feature" else Estimate("dev-1", 7, 12.25, 0.0061, "deepsee-1"))
    old = body[:4] + bytes([version]) + body[5:]
    with pytest.raises(
        MessageError, match=f"protocol version {version} is not supported .this end speaks {messages.PROTOCOL_VERSION}"
    ):
        decode([topic, old])


def test_stream_session_and_device_settings_travel_with_every_window_end_and_estimate():
    from seesys.core.device_settings import DeviceSettings

    settings = DeviceSettings.of("mono", 29.97, 1200, 10, 2, 0.3)
    assert settings.fps == 30  # whole frames per second
    frame = dataclasses.replace(feature(np.ones((4, 4, 3), np.uint8)), stream_session=2**64 - 5, settings=settings)
    out = decode(encode(frame))
    assert (out.stream_session, out.settings) == (2**64 - 5, settings)
    assert decode(encode(feature(np.ones((4, 4, 3), np.uint8)))).settings is None  # may state none: refused
    # A frame without a PSD (between two window ends) carries neither settings nor covariance, nor their bytes.
    between = decode(encode(dataclasses.replace(frame, psd=None, translation_covariance=np.eye(3) * 1e-6)))
    assert between.settings is None and between.translation_covariance is None and between.stream_session == 2**64 - 5
    assert len(encode(dataclasses.replace(frame, psd=None))[1]) == len(encode(feature())[1])
    estimate = decode(encode(Estimate("dev-1", 7, 12.25, 0.0061, "m", 3.5, stream_session=99)))
    assert (estimate.stream_session, estimate.frame_index) == (99, 7)


def test_topics_are_exact_and_device_ids_are_checked():
    assert messages.topic(messages.FEATURE_TOPIC, "dev-1") == b"F/dev-1\x00"
    assert not messages.topic(messages.FEATURE_TOPIC, "dev-10").startswith(
        messages.topic(messages.FEATURE_TOPIC, "dev-1")
    )
    for bad in ("", "a\x00b"):
        with pytest.raises(ValueError, match="device id"):
            messages.topic(messages.ESTIMATE_TOPIC, bad)


@pytest.mark.parametrize("fill", [0.0, 0.05, 0.5, 1.0])
def test_psd_codec_round_trips_any_matrix(fill):
    rng = np.random.default_rng(3)
    psd = np.where(rng.random((96, 128, 3)) < fill, rng.integers(1, 256, (96, 128, 3)), 0).astype(np.uint8)
    np.testing.assert_array_equal(messages.unpack_psd(messages.pack_psd(psd)), psd)


def _stream_psd_round_trip(psd: np.ndarray) -> np.ndarray:
    frame = dataclasses.replace(feature(psd), rts=np.zeros(rts_schema.NUM_CHANNELS, np.float32))
    return decode(encode(frame)).psd


@pytest.mark.parametrize("fill", [0.0, 0.05, 0.5, 1.0])
@pytest.mark.parametrize("shape", [(96, 128, 3), (2, 3, 3), (5, 7, 2), (4, 4, 1)])
def test_the_streams_psd_code_round_trips_any_matrix(fill, shape):
    rng = np.random.default_rng(4)
    psd = np.where(rng.random(shape) < fill, rng.integers(1, 256, shape), 0).astype(np.uint8)
    np.testing.assert_array_equal(_stream_psd_round_trip(psd), psd)


def test_the_streams_psd_code_keeps_inliers_among_keypoints_and_is_smaller_than_the_logs():
    """A PSD as the monitor makes it: inliers on keypoint cells (coded over those cells), map points around."""
    rng = np.random.default_rng(5)
    psd = np.zeros((96, 128, 3), np.uint8)
    keypoints = rng.random((96, 128)) < 0.04
    psd[..., 0] = np.where(keypoints, rng.integers(1, 256, (96, 128)), 0)
    psd[..., 1] = np.where(keypoints & (rng.random((96, 128)) < 0.5), 255, 0)
    yy, xx = np.mgrid[0:96, 0:128]
    psd[..., 2] = np.where(rng.random((96, 128)) < 0.1, 20 + (yy + xx) // 8, 0)
    np.testing.assert_array_equal(_stream_psd_round_trip(psd), psd)
    assert len(messages.pack_stream_psd(psd)) < 0.9 * len(messages.pack_psd(psd))


@pytest.mark.parametrize(
    "cut, message", [("masks", "masks are longer than"), ("values", "keypoint values are cut short")]
)
def test_a_stream_psd_whose_parts_do_not_fit_is_rejected(cut, message):
    psd = np.zeros((4, 4, 3), np.uint8)
    psd[1, 1], psd[2, 3] = (9, 255, 30), (10, 255, 31)
    packed = messages.pack_stream_psd(psd)
    head = struct.Struct("<HHHBBHHH")
    *shape, nested, constant, a, b, c = head.unpack_from(packed)
    constants, rest = packed[head.size : head.size + 1], packed[head.size + 1 :]  # the inlier layer's 255
    masks, plain, differences = rest[:a], rest[a : a + b], rest[a + b :]
    if cut == "masks":  # 10 MB of set bits for 48 cells
        bomb = zlib.compressobj(6, zlib.DEFLATED, -15)
        masks = bomb.compress(b"\xff" * 10_000_000) + bomb.flush()
    else:  # no keypoint values for the two marked cells
        plain = b""
    packed = head.pack(*shape, nested, constant, len(masks), len(plain), c) + constants + masks + plain + differences
    topic, body = encode(feature())
    with pytest.raises(MessageError, match=message):
        decode([topic, body[:-1] + b"\x01" + packed])


def test_rts_rows_at_the_streams_resolution_travel_as_float16_exactly_and_others_as_float32():
    rng = np.random.default_rng(6)
    row = (rng.standard_normal(rts_schema.NUM_CHANNELS) * 10.0 ** rng.integers(-6, 5, rts_schema.NUM_CHANNELS)).astype(
        np.float32
    )
    row[3] = np.nan
    at = messages.stream_resolution(row)
    finite = np.isfinite(row)
    assert np.all(np.abs(at[finite] - row[finite]) <= np.maximum(np.abs(row[finite]) * 2**-11, 6e-8))
    assert np.isnan(at[3]) and not np.array_equal(at, row, equal_nan=True)
    wide = at.copy()
    wide[0] = 1e6  # beyond float16's range: the row goes as float32
    assert messages.stream_resolution(wide)[0] == 1e6
    sizes = {}
    for name, values in (("half", at), ("single", wide), ("unrounded", row)):
        topic, body = encode(dataclasses.replace(feature(), rts=values))
        np.testing.assert_array_equal(decode([topic, body]).rts, values)
        sizes[name] = len(body)
    assert sizes["single"] == sizes["unrounded"] == sizes["half"] + 2 * rts_schema.NUM_CHANNELS


def test_a_feature_frames_device_id_is_its_topics():
    topic, body = encode(feature())
    assert b"dev-1" not in body
    assert decode([messages.topic(messages.FEATURE_TOPIC, "dev-2"), body]).device_id == "dev-2"
    with pytest.raises(MessageError, match="UTF-8"):
        decode([b"F/\xff\x00", body])


def test_a_psd_that_inflates_beyond_its_header_is_rejected():
    bomb = zlib.compress(b"\xff" * 10_000_000)  # 10 MB of "every cell set" for a 4x4x3 header
    data = struct.pack("<HHHI", 4, 4, 3, len(bomb)) + bomb
    with pytest.raises(MessageError, match="does not fit its header"):
        messages.unpack_psd(data)


@pytest.mark.parametrize("values", [b"\x07\x07\x07", b"\x07", b"\x07\x00"])
def test_a_psd_whose_values_do_not_match_its_marked_cells_is_rejected(values):
    mask = np.packbits(np.array([1, 0, 0, 1], bool)).tobytes()  # two cells of a 2x2x1 matrix marked
    packed = zlib.compress(mask + values)
    with pytest.raises(MessageError, match="marked cells"):
        messages.unpack_psd(struct.pack("<HHHI", 2, 2, 1, len(packed)) + packed)


def test_psd_cells_come_back_in_place_across_layers():
    psd = np.zeros((2, 3, 3), np.uint8)
    psd[0, 1, 2], psd[1, 2, 0], psd[1, 0, 1] = 9, 200, 1
    out = messages.unpack_psd(messages.pack_psd(psd))
    assert out.shape == (2, 3, 3) and out.flags.c_contiguous
    np.testing.assert_array_equal(out, psd)


def test_an_estimate_carries_its_heads_thresholds_and_probabilities_and_the_class_survives():
    """Each probability travels with its threshold (float32 both); the head's class read back is the one sent."""
    from seesys.core.exceedance import head_class
    from seesys.core.messages import Exceedance

    for probabilities in ([0.9, 0.6, 0.2], [0.5, 0.5, 0.4999], [0.1, 0.05, 0.0], [1.0, 1.0, 0.75]):
        head = tuple(Exceedance(t, p) for t, p in zip((0.004, 0.008, 0.012), probabilities))
        msg = Estimate("dev-1", 7, 12.25, 0.0061, "deepsee-1", 3.5, 99, head)
        out = decode(encode(msg))
        assert [e.threshold_m for e in out.head] == [float(np.float32(t)) for t in (0.004, 0.008, 0.012)]
        np.testing.assert_array_equal([e.probability for e in out.head], np.float32(probabilities))
        assert head_class(np.array([e.probability for e in out.head])) == head_class(np.array(probabilities))
        assert dataclasses.replace(out, head=()) == dataclasses.replace(msg, head=())
    plain = Estimate("dev-1", 7, 12.25, 0.0061, "deepsee-1", 3.5)
    topic, body = encode(plain)
    assert body[-1] == 0 and decode([topic, body]).head == ()  # no head: a count of 0, nothing after it


@pytest.mark.parametrize(
    "head, problem",
    [
        (((0.008, 0.5), (0.004, 0.5)), "increasing"),
        (((0.004, 0.5), (0.004, 0.4)), "increasing"),
        (((-0.004, 0.5),), "positive"),
        (((0.004, 1.5),), r"\[0, 1\]"),
        (((0.004, math.nan),), r"\[0, 1\]"),
    ],
)
def test_a_head_that_cannot_be_read_is_refused(head, problem):
    from seesys.core.messages import Exceedance

    msg = Estimate("dev-1", 7, 12.25, 0.0061, "deepsee-1", head=tuple(Exceedance(*e) for e in head))
    with pytest.raises(MessageError, match=problem):
        decode(encode(msg))


def _covariance(scale: float) -> np.ndarray:
    a = np.array([[1.0, 0.2, -0.1], [0.0, 0.8, 0.3], [0.0, 0.0, 0.5]])
    return a @ a.T * scale


@pytest.mark.parametrize("scale", [1e-8, 1e-5, 1.0])  # σ of 0.1 mm, 3 mm and 1 m: float16 in mm² up to ~0.25 m
def test_a_translation_covariance_travels_with_the_frame_and_its_estimate_at_the_wires_resolution(scale):
    covariance = _covariance(scale)
    frame = dataclasses.replace(feature(np.ones((4, 4, 3), np.uint8)), translation_covariance=covariance)
    estimate = Estimate("dev-1", 7, 12.25, 0.0061, "deepsee-1", translation_covariance=covariance)
    for message in (frame, estimate):
        out = decode(encode(message)).translation_covariance
        assert out is not None and np.array_equal(out, out.T)
        np.testing.assert_array_equal(out, messages.covariance_resolution(covariance))
        np.testing.assert_allclose(out, covariance, rtol=1e-3, atol=1e-3 * scale)
    small, large = (len(encode(dataclasses.replace(frame, translation_covariance=c))[1]) for c in (None, covariance))
    assert large - small == (12 if scale < 1 else 24)  # six float16 (float32 beyond float16's range)
    assert decode(encode(feature(np.ones((4, 4, 3), np.uint8)))).translation_covariance is None


def test_a_covariance_that_cannot_be_one_is_refused():
    window_end = feature(np.ones((4, 4, 3), np.uint8))
    topic, body = encode(dataclasses.replace(window_end, translation_covariance=_covariance(1e-6)))
    start = body.index(messages._pack_covariance(_covariance(1e-6)))
    negative = np.array([-1, 0, 0, 1, 0, 1], "<f2").tobytes()
    with pytest.raises(MessageError, match="non-negative diagonal"):
        decode([topic, body[: start + 1] + negative + body[start + 13 :]])
    with pytest.raises(MessageError, match="covariance values of 3 bytes"):
        decode([topic, body[:start] + bytes([3]) + body[start + 1 :]])
