"""The monitor beside real ORB-SLAM3 on the embedded sample: logs, stream, and features checked against the
sample's ground truth."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from seesys.core import rts_schema, session_layout
from seesys.core.windows import assemble_windows
from seesys.io.config import config_dir
from seesys.io.rts_log import read_feature_frames, read_psd_log, read_rts_csv
from slam_monitor.device_worker import SessionOptions, run_device_session
from slam_monitor.monitor import RtsMonitor
from slam_monitor.monitor_config import load_monitor_config
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.slam_features import relative_motion
from slam_monitor.stream import FeaturePublisher, FeatureSubscriber

pytestmark = pytest.mark.slam

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / "data" / "sample"
ROTATIONS = ("rel_roll", "rel_pitch", "rel_yaw")


class Collector(threading.Thread):
    """Subscribes to a feature stream and keeps what arrives until told to stop."""

    def __init__(self, endpoint: str):
        super().__init__(daemon=True)
        self.subscriber = FeatureSubscriber(endpoint)
        self.frames = []
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            frame = self.subscriber.receive(timeout_ms=100)
            if frame is not None:
                self.frames.append(frame)
        self.subscriber.close()


def ground_truth_motion(session: Path) -> dict[float, np.ndarray]:
    """Ground-truth (roll, pitch, yaw) per frame from the session's groundtruth.tum, keyed by timestamp."""
    gt = np.loadtxt(session / "groundtruth.tum")
    poses = []
    for row in gt:
        t = np.eye(4)
        t[:3, :3] = Rotation.from_quat(row[4:8]).as_matrix()
        t[:3, 3] = row[1:4]
        poses.append(t)
    motion = {}
    for k in range(1, len(gt)):
        m = relative_motion(poses[k - 1], poses[k])
        motion[round(gt[k, 0], 4)] = np.array([m.roll, m.pitch, m.yaw])
    return motion


def check_session(
    session: Path,
    min_tracked: float,
    min_rotation_corr: float | None,
    depth: bool,
    min_sign_agreement: float = 0.9,
    max_median_rotation_error: float = 0.002,
) -> None:
    table = read_rts_csv(session)
    frames = table["frame_index"].to_numpy()
    assert (np.diff(frames) == 1).all()
    tracked = table[table["tracking_state"].isin(["OK", "OK_KLT"])]
    assert len(tracked) >= min_tracked * len(table)
    depth_channels = list(rts_schema.channel_names("depth"))
    sparse = [*depth_channels, "flow_disagreement"]  # the second opinion once its span is whole (and RGB-D only)
    others = [name for name in rts_schema.CHANNEL_NAMES if name not in sparse]
    assert not tracked[others].isna().any().any(), "NaN on a tracked frame"
    if depth:  # every RGB-D frame has them; the registration once tracked frames have given it enough depth edges
        assert not table[["depth_holes", "depth_noise"]].isna().any().any()
        registration = table["depth_registration"]
        assert np.isnan(registration.iloc[0]) and registration.iloc[len(table) // 4 :].notna().all()
        # An ideal render: 16-bit depth quantisation only, and depth edges on the colour edges (f = 525 px).
        assert (table["depth_noise"] < 1e-3).all()
        assert registration.max() < 0.5 / 525, registration.max() * 525
        # A hop every 5th frame, held between: a value from the second hop frame on, wherever the flow followed.
        flow = table.set_index("frame_index")["flow_disagreement"]
        assert flow.loc[: 2 * load_monitor_config().second_opinion.hop_frames - 1].isna().all()
        assert flow.notna().mean() > 0.8 and (flow.dropna() < 30).all(), flow.describe()  # mm, on an ideal render
    else:
        assert table[sparse].isna().all().all()
    assert (tracked["matched_inliers"] >= 10).all()
    assert (tracked["avg_mp_depth"] > 0).all() and (tracked["local_mapping_visual_error"] < 3).all()

    psds = list(read_psd_log(session))
    assert [r.frame_index for r in psds] == [i for i in frames if load_monitor_config().windows.is_psd_frame(i)]
    assert all(r.psd.shape == (96, 128, 3) and r.psd.dtype == np.uint8 for r in psds)
    last = [r.psd for r in psds if r.frame_index in set(tracked["frame_index"])][-1]
    assert all(np.count_nonzero(last[..., layer]) > 50 for layer in range(3))

    # every tracked frame's predicted pose covariance: symmetric positive definite, positions to within centimetres
    logged = pd.read_csv(session / session_layout.POSE_COVARIANCE_CSV)
    assert set(logged.frame_index) <= set(tracked.frame_index) and len(logged) >= 0.95 * len(tracked)
    covariances = session_layout.covariance_matrices(logged[list(session_layout.POSE_COVARIANCE_COLUMNS[2:])])
    assert (np.linalg.eigvalsh(covariances) > 0).all()
    position_sigma = np.sqrt(np.trace(covariances[:, :3, :3], axis1=1, axis2=2))
    assert (position_sigma < 0.05).all() and (position_sigma > 1e-5).all()

    # relative rotation agrees with the ground truth in sign and size (scale-free, so mono too), on frames whose
    # previous frame was tracked (the first frame after a gap has zero motion by definition)
    gt = ground_truth_motion(session)
    continuing = tracked[tracked["frame_index"].isin(tracked["frame_index"] + 1)]
    rows = [
        (gt[round(t, 4)], r)
        for t, r in zip(continuing["timestamp"], continuing[list(ROTATIONS)].to_numpy())
        if round(t, 4) in gt
    ]
    truth, measured = (np.array(x) for x in zip(*rows))
    for k, name in enumerate(ROTATIONS):
        strong = np.abs(truth[:, k]) > 0.004
        if strong.sum() > 10:
            agree = np.mean(np.sign(truth[strong, k]) == np.sign(measured[strong, k]))
            assert agree > min_sign_agreement, f"{name} sign agrees on {agree:.0%} of {strong.sum()} frames"
    if min_rotation_corr is not None:
        # Pooled over the three axes: on a walk the smallest axis moves a few mrad per frame, near the noise.
        assert np.corrcoef(truth.ravel(), measured.ravel())[0, 1] > min_rotation_corr
    assert np.median(np.abs(truth - measured)) < max_median_rotation_error


@pytest.mark.system
def test_rgbd_session_logs_and_streams_every_frame(tmp_path):
    out = tmp_path / "session"
    out.mkdir()
    publisher = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=1000)
    collector = Collector(publisher.bound_endpoint)
    collector.start()
    monitor = RtsMonitor(load_monitor_config(), out, publisher)
    result = run_device_session(
        SessionOptions(source=f"tum:{SAMPLE}", mode=SlamMode.RGBD, out_dir=out), observers=[monitor]
    )
    collector.stop.set()
    collector.join()
    stats = monitor.stats

    assert stats.frames_seen == result.frames
    assert stats.frames_processed + stats.frames_dropped == result.frames
    check_session(out, min_tracked=0.9, min_rotation_corr=0.9, depth=True)

    # what crossed the wire is what was logged, frame by frame (subscribers may join a little late)
    logged = {f.frame_index: f for f in read_feature_frames(out, monitor.config.device_id)}
    assert len(collector.frames) >= 0.8 * stats.frames_processed
    for f in collector.frames:
        np.testing.assert_array_equal(f.rts, logged[f.frame_index].rts)
        assert (f.psd is None) == (logged[f.frame_index].psd is None)
        if f.psd is not None:
            np.testing.assert_array_equal(f.psd, logged[f.frame_index].psd)
    assert len(list(assemble_windows(logged.values(), monitor.config.windows))) >= 8


def configs_with_endpoint(tmp_path: Path, endpoint: str) -> Path:
    """A copy of configs/ whose network.toml puts the feature stream on ``endpoint``."""
    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    network = (configs / "network.toml").read_text().splitlines()
    (configs / "network.toml").write_text(
        "\n".join(
            f'features_endpoint = "{endpoint}"' if line.startswith("features_endpoint") else line for line in network
        )
        + "\n"
    )
    return configs


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.system
def test_monitor_run_command_mono_with_stream(tmp_path):
    endpoint = f"tcp://127.0.0.1:{_free_port()}"
    configs = configs_with_endpoint(tmp_path, endpoint)
    collector = Collector(endpoint)
    collector.start()
    out = tmp_path / "mono"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "monitor",
            "run",
            "--source",
            f"tum:{SAMPLE}",
            "--mode",
            "mono",
            "--out",
            str(out),
            "--max-frames",
            "90",
            "--stream",
            "--device-id",
            "phone-1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "SEESYS_CONFIG_DIR": str(configs)},
    )
    collector.stop.set()
    collector.join()
    assert run.returncode == 0, run.stderr
    assert "monitor: " in run.stdout and "frames processed" in run.stdout
    assert "kbit/s" in run.stdout
    # Monocular ORB-SLAM3 loses frames and its per-frame rotation jitters by up to ~0.05 rad on a few frames when
    # the CPU is shared (pose error is what SEESys estimates): signs are checked, not the correlation, and one
    # jittered frame among the few with strong yaw (8 of 9 agreed in one full-suite run) is not a sign error; a
    # flipped convention agrees on almost none, chance on half.
    # A monocular map is weaker when its local mapping thread is starved: 2.35 mrad seen with the machine at load 9.
    check_session(
        out,
        min_tracked=0.3,
        min_rotation_corr=None,
        depth=False,
        min_sign_agreement=0.75,
        max_median_rotation_error=0.003,
    )
    assert collector.frames and {f.device_id for f in collector.frames} == {"phone-1"}


@pytest.mark.system
def test_stream_endpoint_in_use_is_a_one_line_error(tmp_path):
    squatter = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=1)
    configs = configs_with_endpoint(tmp_path, squatter.bound_endpoint)
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "seesys",
            "monitor",
            "run",
            "--source",
            f"tum:{SAMPLE}",
            "--out",
            str(tmp_path / "s"),
            "--max-frames",
            "5",
            "--stream",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "SEESYS_CONFIG_DIR": str(configs)},
    )
    squatter.close()
    assert run.returncode == 2
    assert run.stderr.strip().splitlines()[-1].startswith("seesys: error: cannot bind the feature stream endpoint")
    assert "Traceback" not in run.stderr
