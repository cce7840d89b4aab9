import json

import numpy as np
import pandas as pd
import pytest
from evo.tools import file_interface
from scipy.spatial.transform import Rotation

from seesys.core import session_layout
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses
from seesys.io import session_files
from slam_monitor import session
from slam_monitor.tracker import TrackOutput


def output(index, state, pose_wc=None):
    return TrackOutput(
        frame_index=index,
        timestamp=100.0 + index / 30,
        state=state,
        pose_cw=None if pose_wc is None else np.linalg.inv(pose_wc),
        pose_wc=pose_wc,
        num_tracked_points=300 + index,
        track_ms=12.5,
        keypoints=np.zeros((0, 2), np.float32),
        map_points=np.zeros((0, 3), np.float32),
        map_changed=False,
    )


def pose(index):
    p = np.eye(4)
    p[:3, :3] = Rotation.from_euler("z", [[0.1 * index]]).as_matrix()[0]
    p[:3, 3] = [index, 2.0 * index, -1.0]
    return p


def test_rows_are_on_disk_as_soon_as_written(tmp_path):
    folder = session.prepare_session_folder(tmp_path / "s")
    writer = session.SessionWriter(folder, {"source": "tum:x", "mode": "rgbd"})
    writer.write_frame(output(0, TrackingState.NOT_INITIALIZED))
    writer.write_frame(output(1, TrackingState.OK, pose(1)))
    writer.write_frame(output(2, TrackingState.OK, pose(2)))
    writer.write_frame(output(3, TrackingState.LOST))
    # read back while the writer is still open, as after a crash
    frames = pd.read_csv(folder / session_layout.FRAMES_CSV)
    assert list(frames.columns) == ["frame_index", "timestamp", "state", "tracked_points", "track_ms"]
    assert list(frames.state) == ["NOT_INITIALIZED", "OK", "OK", "LOST"]
    trajectory = file_interface.read_tum_trajectory_file(str(folder / session_layout.TRAJECTORY))
    assert trajectory.num_poses == 2
    np.testing.assert_allclose(trajectory.poses_se3[1], pose(2), atol=1e-8)
    manifest = session_files.read_manifest(folder)
    assert manifest["status"] == "running" and manifest["source"] == "tum:x"
    assert manifest["packages"]["pyorbslam3"] == "0.1.1" and "start_time" in manifest
    writer.finish("completed")
    manifest = session_files.read_manifest(folder)
    assert (manifest["status"], manifest["frames"], manifest["frames_tracked"]) == ("completed", 4, 2)


def test_ground_truth_is_a_tum_file(tmp_path):
    folder = session.prepare_session_folder(tmp_path / "s")
    writer = session.SessionWriter(folder, {})
    truth = Poses(np.array([1.0, 2.0]), np.array([[0, 0, 0], [1, 2, 3.0]]), np.array([[0, 0, 0, 1.0]] * 2))
    writer.write_ground_truth(truth)
    trajectory = file_interface.read_tum_trajectory_file(str(folder / session_layout.GROUND_TRUTH))
    np.testing.assert_allclose(trajectory.positions_xyz, truth.positions)


def test_manifest_updates_replace_the_file_whole(tmp_path):
    session_files.update_manifest(tmp_path, a=1)
    session_files.update_manifest(tmp_path, b=[1, 2])
    assert json.loads((tmp_path / session_layout.MANIFEST).read_text()) == {"a": 1, "b": [1, 2]}
    assert not list(tmp_path.glob("*.tmp"))


def test_new_session_clears_old_device_files_only(tmp_path):
    (tmp_path / session_layout.FRAMES_CSV).write_text("old")
    (tmp_path / "rts.csv").write_text("monitor's")
    session.prepare_session_folder(tmp_path)
    assert not (tmp_path / session_layout.FRAMES_CSV).exists() and (tmp_path / "rts.csv").exists()


def test_unwritable_folder_is_a_clear_error(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(session.SeesysError, match="cannot create the session folder"):
        session.prepare_session_folder(tmp_path / "file" / "s")
