"""Motion capture: the clock offset and the marker-to-camera transform of a simulated rigid body are recovered
(within 2 ms, 1 mm and 0.5 degrees), the calibrated ground truth is the camera's true trajectory, Vicon CSV
exports import, and live logging through motioncapture's mock backend writes poses stamped on receipt."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from testkit.mocap import MARKER_CAMERA, OFFSET_S, camera_in_vicon, write_simulated_session
from testkit.ports import refused_port

from seesys.core.errors import SeesysError
from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_tum, write_tum
from study.config import load_study_config
from study.mocap.calibrate import calibrate_session
from study.mocap.clock import CalibrationError, estimate_clock_offset
from study.mocap.importers import MocapImportError, read_vicon_csv
from study.mocap.logger import MocapUnavailable, connect

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def simulated_session(tmp_path):
    return write_simulated_session(tmp_path)


@pytest.mark.system
def test_offset_and_hand_eye_recovered_and_ground_truth_is_the_camera(simulated_session):
    cfg = load_study_config()
    result = calibrate_session(simulated_session, cfg.calibration, cfg.mocap.body)
    assert abs(result.clock.offset_s - OFFSET_S) < 0.002
    assert result.clock.peak_correlation > 0.95
    x = result.marker_camera
    assert np.linalg.norm(x[:3, 3] - MARKER_CAMERA[:3, 3]) < 0.001
    assert np.degrees(Rotation.from_matrix(x[:3, :3].T @ MARKER_CAMERA[:3, :3]).magnitude()) < 0.5
    assert result.hand_eye.residual_rotation_deg_median < 0.5
    # groundtruth.tum: the camera's poses in the Vicon frame on the camera clock.
    truth = read_tum(simulated_session / "groundtruth.tum")
    inside = (truth.timestamps > 1001) & (truth.timestamps < 1029)
    true = camera_in_vicon(truth.timestamps[inside] - 1000.0)
    assert np.max(np.linalg.norm(truth.positions[inside] - true[:, :3, 3], axis=1)) < 0.003
    assert (simulated_session / "calibration.json").is_file()


@pytest.mark.system
def test_calibrate_command_keeps_existing_ground_truth(simulated_session):
    (simulated_session / "groundtruth.tum").write_text("# kept\n")
    run = lambda *extra: subprocess.run(  # noqa: E731
        [
            sys.executable,
            "-m",
            "seesys",
            "study",
            "calibrate",
            str(simulated_session),
            *extra,
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    refused = run()
    assert refused.returncode == 2 and "--overwrite" in refused.stderr
    assert (simulated_session / "groundtruth.tum").read_text() == "# kept\n"
    done = run("--overwrite")
    assert done.returncode == 0, done.stderr
    assert "clock offset: 123." in done.stdout
    assert len(read_tum(simulated_session / "groundtruth.tum")) > 3000


def test_a_body_that_does_not_rotate_cannot_give_an_offset():
    cfg = load_study_config().calibration
    times = np.arange(0, 10, 0.01)
    still = Poses(times, np.zeros((len(times), 3)), np.tile([0, 0, 0, 1.0], (len(times), 1)))
    with pytest.raises(CalibrationError, match="does not rotate"):
        estimate_clock_offset(still, still, cfg)


def test_vicon_csv_import(tmp_path):
    """The Nexus layout: blocks, rate, Subject:Segment, helical angles in degrees, millimetres, occlusion gaps."""
    rotvec_deg = np.array([10.0, -20.0, 30.0])
    rows = [
        "Devices",
        "1000",
        "",
        "Frame,Sub Frame",
        "",
        "",
        "Segments",
        "100",
        ",,handheld:handheld,,,,,,other:other",
        "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,RX,RY,RZ,TX,TY,TZ",
        ",,deg,deg,deg,mm,mm,mm,deg,deg,deg,mm,mm,mm",
    ]
    for frame in range(1, 6):
        pose = "" if frame == 3 else ",".join(map(str, [*rotvec_deg, 100.0 * frame, 200.0, 1500.0]))
        rows.append(f"{frame},0,{pose or ',,,,,'},0,0,0,0,0,0")
    rows += ["", "Trajectories", "100"]
    path = tmp_path / "export.csv"
    path.write_text("\n".join(rows) + "\n")
    poses = read_vicon_csv(path, "handheld")
    assert np.allclose(poses.timestamps, [0.0, 0.01, 0.03, 0.04])
    assert np.allclose(poses.positions[:, 0], [0.1, 0.2, 0.4, 0.5])
    assert np.allclose(poses.rotations[0].as_rotvec(), np.radians(rotvec_deg))
    with pytest.raises(MocapImportError, match="no body 'wand'"):
        read_vicon_csv(path, "wand")


@pytest.mark.system
def test_live_logging_with_the_mock_backend_stamps_on_receipt(tmp_path):
    before = time.time()
    done = subprocess.run(
        [sys.executable, "-m", "seesys", "study", "mocap", "log", "--out", str(tmp_path), "--duration", "0.5"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
        env=os.environ,
    )
    after = time.time()
    assert done.returncode == 0, done.stderr
    poses = read_tum(tmp_path / "mocap.tum")
    assert len(poses) > 5
    assert np.all(np.diff(poses.timestamps) > 0)
    assert before < poses.timestamps[0] and poses.timestamps[-1] < after
    assert np.allclose(poses.positions, [0.1, 0.2, 1.5], atol=1e-6)  # the mock body of configs/study.toml


def test_an_unreachable_server_is_an_error_not_a_hang():
    with refused_port() as port:
        cfg = dataclasses.replace(load_study_config().mocap, backend="vicon", hostname="127.0.0.1", port=port)
        with pytest.raises(MocapUnavailable, match=f"127.0.0.1:{port}"):
            connect(cfg)
    assert issubclass(MocapUnavailable, SeesysError)


def test_an_export_timed_from_the_capture_start_is_found(simulated_session):
    """A Vicon export's time starts at 0: the search starts from the recordings' start times."""
    cfg = load_study_config()
    markers = read_tum(simulated_session / "mocap.tum")
    capture_start = markers.timestamps[0] - 0.4  # the capture started 0.4 s before the first pose logged
    write_tum(
        simulated_session / "export.tum",
        Poses(markers.timestamps - capture_start, markers.positions, markers.quaternions_xyzw),
    )
    result = calibrate_session(
        simulated_session, cfg.calibration, cfg.mocap.body, mocap=simulated_session / "export.tum"
    )
    assert abs(result.clock.offset_s - (OFFSET_S + capture_start)) < 0.002
