"""The monitor's per-frame assembly, its thread (bounded queue, drops counted) and its session logs.

The real-SLAM runs are in test_monitor_slam.py; here the inputs are constructed so that every value is known.
"""

from __future__ import annotations

import dataclasses
import json
import types

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from testkit.stream import wait_until_subscribed

from seesys.core import rts_schema
from seesys.core.camera import Intrinsics
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState
from seesys.core.windows import assemble_windows
from seesys.io.config import replace_fields
from seesys.io.rts_log import MonitorLogError, read_feature_frames, read_psd_log, read_rts_csv, schema_metadata
from slam_monitor.frame import Frame
from slam_monitor.monitor import FeatureExtractor, MonitorInput, RtsMonitor
from slam_monitor.monitor_config import load_monitor_config
from slam_monitor.stream import FeaturePublisher, FeatureSubscriber

INTR = Intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
CONFIG = load_monitor_config()


def pose_wc(yaw: float, forward: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("y", yaw).as_matrix()
    t[:3, 3] = t[:3, :3] @ [0.0, 0.0, forward]
    return t


def scene_points(pose: np.ndarray, n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """World points in front of ``pose`` and their pixel projections."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([10, 10], [630, 470], (n, 2))
    z = rng.uniform(1.0, 3.0, n)
    pc = np.column_stack([(uv[:, 0] - 320) * z / 500, (uv[:, 1] - 240) * z / 500, z])
    return pc @ pose[:3, :3].T + pose[:3, 3], uv


def track_output(index: int, state: TrackingState, pose: np.ndarray | None, points_w, keypoints):
    """A per-frame record with the fields of slam_monitor.tracker.TrackOutput."""
    return types.SimpleNamespace(
        frame_index=index,
        state=state,
        pose_wc=pose,
        pose_cw=None if pose is None else np.linalg.inv(pose),
        num_tracked_points=len(points_w),
        keypoints=np.asarray(keypoints, dtype=np.float32),
        map_points=np.asarray(points_w, dtype=np.float32),
        map_changed=False,
    )


def gray(index: int) -> np.ndarray:
    return np.random.default_rng(index).integers(0, 256, (480, 640), dtype=np.uint8)


def test_feature_row_of_constructed_frames():
    extractor = FeatureExtractor(CONFIG)
    first, second = pose_wc(0.0, 0.0), pose_wc(0.02, 0.05)
    points_w, uv0 = scene_points(first)
    in_second = (np.column_stack([points_w, np.ones(len(points_w))]) @ np.linalg.inv(second).T)[:, :3]
    uv1 = (in_second @ INTR.matrix().T)[:, :2] / in_second[:, 2:3]

    def item(index, state, pose, prev, uv):
        out = track_output(index, state, pose, points_w, uv)
        return MonitorInput(
            Frame(index, index / 30, gray(index), INTR),
            state,
            out.pose_cw,
            out.pose_wc,
            prev,
            out.num_tracked_points,
            out.keypoints,
            out.map_points,
            False,
            0,
        )

    row_of = {name: i for i, name in enumerate(rts_schema.CHANNEL_NAMES)}
    f10 = extractor.extract(item(10, TrackingState.OK, first, None, uv0))
    f11 = extractor.extract(item(11, TrackingState.OK, second, first, uv1))
    lost = extractor.extract(item(12, TrackingState.LOST, None, None, uv1))

    assert (f10.frame_index, f11.frame_index) == (10, 11) and f11.timestamp == pytest.approx(11 / 30)
    assert f10.rts[row_of["rel_yaw"]] == 0.0  # no previous pose: no motion
    # Values at the stream's resolution: float16, within 2^-11 of the value
    assert f11.rts[row_of["rel_yaw"]] == pytest.approx(0.02, rel=2**-11)
    assert f11.rts[row_of["rel_tz"]] == pytest.approx(0.05, rel=2**-11)
    assert f11.rts[row_of["brightness"]] == pytest.approx(gray(11).mean() / 255, rel=2**-11)
    assert f11.rts[row_of["matched_inliers"]] == 300
    assert f11.rts[row_of["local_mapping_visual_error"]] == pytest.approx(0.0, abs=1e-3)
    # No depth image: the depth channels and the second opinion (RGB-D only) unknown.
    depth = [row_of[name] for name in (*rts_schema.channel_names("depth"), *rts_schema.channel_names("second_opinion"))]
    assert depth and np.isnan(f11.rts[depth]).all()
    # Exact projections: no residual, every inlier within the gate; a plane of points spread over the image.
    assert (
        f11.rts[row_of["residual_median"]] == pytest.approx(0.0, abs=1e-3)
        and f11.rts[row_of["residual_over_gate"]] == 0
    )
    assert f11.rts[row_of["translation_sigma"]] > 0 and f11.rts[row_of["image_coverage"]] > 0.5
    assert not np.isnan(np.delete(f10.rts, depth)).any() and not np.isnan(np.delete(f11.rts, depth)).any()
    # PSD on tau-th frames only; all points matched → as many inlier cells as keypoint cells
    assert f10.psd is not None and f11.psd is None and f10.psd.shape == (96, 128, 3)
    assert np.count_nonzero(f10.psd[..., 1]) == np.count_nonzero(f10.psd[..., 0]) > 100
    # a lost frame keeps its image channels and has no tracking/mapping values
    image = [row_of[n] for n in ("brightness", "contrast", "entropy", "laplacian")]
    assert np.isfinite(lost.rts[image]).all()
    assert np.isnan(np.delete(lost.rts, image)).all()


def _feed(monitor: RtsMonitor, n: int) -> None:
    pose = pose_wc(0.0, 0.0)
    points_w, uv = scene_points(pose)
    for i in range(n):
        monitor.on_frame(
            Frame(i, 100 + i / 30, gray(i % 3), INTR), track_output(i, TrackingState.OK, pose, points_w, uv)
        )


def test_monitor_drops_and_counts_when_behind(tmp_path):
    monitor = RtsMonitor(replace_fields(CONFIG, queue_size=1), tmp_path)
    _feed(monitor, 200)  # far faster than the monitor's ~ms of work per frame
    stats = monitor.close()
    assert stats.frames_seen == 200
    assert stats.frames_dropped > 0
    assert stats.frames_processed + stats.frames_dropped == 200
    table = read_rts_csv(tmp_path)
    assert len(table) == stats.frames_processed
    assert table["frame_index"].is_monotonic_increasing
    assert (tmp_path / "monitor_stats.json").is_file()


def test_logs_round_trip_into_windows(tmp_path):
    monitor = RtsMonitor(replace_fields(CONFIG, queue_size=1000), tmp_path)
    _feed(monitor, 71)
    monitor.close()
    frames = list(read_feature_frames(tmp_path, "dev"))
    assert [f.frame_index for f in frames] == list(range(71))
    stride = CONFIG.windows.end_stride
    assert [f.frame_index for f in frames if f.psd is not None] == list(range(0, 71, stride))
    windows = list(assemble_windows(frames, CONFIG.windows))
    assert [w.frame_index for w in windows] == list(range(30, 71, stride))
    assert windows[0].psd.shape == (4, 96, 128, 3)


def test_psd_chunks_and_a_record_cut_by_a_crash(tmp_path):
    monitor = RtsMonitor(
        replace_fields(CONFIG, queue_size=1000, log=dataclasses.replace(CONFIG.log, psd_chunk_records=3)), tmp_path
    )
    _feed(monitor, 71)
    monitor.close()
    chunks = sorted((tmp_path / "psd").glob("psd_*.bin"))
    assert len(chunks) == -(-len(range(0, 71, CONFIG.windows.end_stride)) // 3)
    last = chunks[-1].read_bytes()
    chunks[-1].write_bytes(last[:-20])
    assert [r.frame_index for r in read_psd_log(tmp_path)] == list(range(0, 70, CONFIG.windows.end_stride))
    chunks[0].write_bytes(chunks[0].read_bytes()[:-20])
    with pytest.raises(MonitorLogError, match="truncated PSD record"):
        list(read_psd_log(tmp_path))


def test_bad_rts_log_is_a_clear_error(tmp_path):
    with pytest.raises(MonitorLogError, match="missing"):
        read_rts_csv(tmp_path)
    (tmp_path / "rts.csv").write_text("frame_index,timestamp,brightness\n0,1.0,0.5\n")
    with pytest.raises(MonitorLogError, match="has no rts.json: its rts.csv was written by an older SEESys"):
        read_rts_csv(tmp_path)
    meta = schema_metadata()
    (tmp_path / "rts.json").write_text(json.dumps(meta))
    with pytest.raises(MonitorLogError, match="do not match RTS schema"):
        read_rts_csv(tmp_path)
    other = rts_schema.SCHEMA_VERSION + 1
    (tmp_path / "rts.json").write_text(json.dumps({**meta, "rts_schema_version": other}))
    with pytest.raises(MonitorLogError, match=f"rts.csv uses RTS schema v{other}"):
        read_rts_csv(tmp_path)


def test_streamed_frames_say_how_many_the_device_skipped(tmp_path):
    pub = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=10_000)
    sub = FeatureSubscriber(pub.bound_endpoint, None, receive_high_water_mark=10_000)
    probe = FeatureFrame("probe", 0, 0.0, TrackingState.OK, np.zeros(rts_schema.NUM_CHANNELS, np.float32))
    wait_until_subscribed(lambda: pub.publish(probe), sub, "probe")
    monitor = RtsMonitor(replace_fields(CONFIG, queue_size=1), tmp_path, pub)
    _feed(monitor, 200)
    stats = monitor.close()
    received = []
    while len(received) < stats.frames_processed:
        frame = sub.receive(timeout_ms=5000)
        assert frame is not None, f"{len(received)} of {stats.frames_processed} streamed frames arrived"
        received.append(frame.frame_index)
    loss = sub.losses.devices[CONFIG.device_id]
    assert stats.frames_dropped > 0
    assert loss.lost_in_transit == 0
    assert loss.skipped_by_device == received[-1] - received[0] + 1 - len(received) > 0
    sub.close()


def test_a_failure_in_the_monitor_thread_stops_the_monitor_not_the_session(tmp_path):
    monitor = RtsMonitor(replace_fields(CONFIG, queue_size=100), tmp_path)
    _feed(monitor, 3)
    bad = track_output(3, TrackingState.OK, pose_wc(0, 0), np.zeros((0, 3)), np.zeros((0, 2)))
    monitor.on_frame(Frame(3, 0.1, np.zeros((480, 640, 3), dtype=np.uint8), INTR), bad)
    stats = monitor.close()
    assert stats.error.startswith("frame 3: ValueError") and "uint8 gray" in stats.error
    assert "Traceback" in stats.error_traceback
    assert read_rts_csv(tmp_path)["frame_index"].tolist() == [0, 1, 2]
    assert json.loads((tmp_path / "monitor_stats.json").read_text())["error"] == stats.error


def test_the_default_device_id_is_unique_per_host_and_camera_and_stable():
    from slam_monitor.monitor_config import resolve_device_id

    assert load_monitor_config().device_id == "auto"
    assert resolve_device_id("auto", "realsense:123456789012", host="lab-pc") == "lab-pc:realsense:123456789012"
    assert resolve_device_id("", "realsense:", host="lab-pc") == "lab-pc:realsense:default"
    assert resolve_device_id("auto", "tum:/data/rooms/office/", host="pi") == "pi:tum:office"
    assert resolve_device_id("auto", "tum:data/sample") == resolve_device_id("auto", "tum:data/sample")
    assert resolve_device_id("auto", "tum:a", host="one") != resolve_device_id("auto", "tum:a", host="two")
    assert resolve_device_id("phone-1", "realsense:", host="lab-pc") == "phone-1"  # an id given is kept
