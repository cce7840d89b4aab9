"""ROS bags as a frame source: ROS 1 and ROS 2 bags written with rosbags from the embedded sample."""

import dataclasses
import itertools
import shutil

import numpy as np
import pandas as pd
import pytest
from testkit.bags import write_sample_bag
from testkit.sample import SAMPLE, run_seesys

from seesys.core import session_layout
from seesys.core.pose_covariance import relative_translation_covariance
from seesys.io.core_settings import load_label_config
from seesys.io.session_labels import label_session
from seesys.io.trajectory_files import read_tum
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.sources import SourceError, load_camera_config, open_source, parse_source_spec
from slam_monitor.trajectory_metrics import summarize_session

BAGS = {"ros2": ("bag2", False), "ros1": ("sample.bag", True)}


@pytest.fixture(scope="module", params=sorted(BAGS))
def sample_bag(request, tmp_path_factory):
    name, ros1 = BAGS[request.param]
    return write_sample_bag(SAMPLE, tmp_path_factory.mktemp(request.param) / name, ros1=ros1)


def with_rosbag(**changes):
    """configs/camera.toml with some [rosbag] keys changed."""
    config = load_camera_config()
    return dataclasses.replace(config, rosbag=dataclasses.replace(config.rosbag, **changes))


def open_spec(text, with_depth=True, config=None):
    return open_source(parse_source_spec(text), config or load_camera_config(), with_depth)


@pytest.mark.system
def test_a_bag_yields_the_frames_depth_intrinsics_and_ground_truth_of_the_folder_it_came_from(sample_bag):
    with open_spec(f"tum:{SAMPLE}") as tum, open_spec(f"rosbag:{sample_bag}") as bag:
        assert bag.frame_count == tum.frame_count == 150
        assert bag.intrinsics == tum.intrinsics
        assert bag.fps == pytest.approx(tum.fps, rel=1e-3)
        for ours, theirs in itertools.islice(zip(bag.frames(), tum.frames()), 5):
            assert ours.index == theirs.index and ours.timestamp == pytest.approx(theirs.timestamp, abs=1e-9)
            assert np.array_equal(ours.gray, theirs.gray)
            # the ROS 1 bag holds millimetres (REP 118), the TUM PNGs 1/5000 m
            assert np.abs(ours.depth - theirs.depth).max() <= 0.0005
        truth, expected = bag.ground_truth(), tum.ground_truth()
    assert np.allclose(truth.timestamps, expected.timestamps, atol=1e-9, rtol=0)
    assert np.allclose(truth.positions, expected.positions) and np.allclose(
        truth.quaternions_xyzw, expected.quaternions_xyzw
    )


def test_a_ros2_storage_file_opens_its_bag_folder(tmp_path, small_tum):
    bag = write_sample_bag(small_tum, tmp_path / "bag", ros1=False)
    storage = next(bag.glob("*.db3"))
    with open_spec(f"rosbag:{storage}", with_depth=False) as source:
        assert source.frame_count == 12 and not source.has_depth


@pytest.mark.system
def test_a_bag_without_an_image_topic_is_a_one_line_error_naming_its_topics(tmp_path, small_tum):
    bag = write_sample_bag(small_tum, tmp_path / "bag", ros1=False, image_topic=None)
    result = run_seesys("track", "--source", f"rosbag:{bag}", "--mode", "rgbd", "--out", str(tmp_path / "s"))
    assert result.returncode == 2
    message = result.stderr.strip()
    assert len(message.splitlines()) == 1 and "no image topic" in message
    for topic in (
        "/camera/aligned_depth_to_color/image_raw (sensor_msgs/msg/Image)",
        "/mocap/camera_pose",
        "/camera/color/camera_info",
    ):
        assert topic in message


def test_topics_named_in_the_configuration_are_checked(tmp_path, small_tum):
    bag = write_sample_bag(small_tum, tmp_path / "bag.bag", ros1=True, image_topic="/left/image")
    named = with_rosbag(image_topic="/cam0/image_raw")
    with pytest.raises(SourceError, match=r"image topic /cam0/image_raw is not in the bag \(it has: .*/left/image"):
        open_spec(f"rosbag:{bag}", config=named)
    with open_spec(f"rosbag:{bag}") as source:
        assert source.topics.image == "/left/image" and source.topics.ground_truth == "/tf"


def test_not_a_bag_is_an_error(tmp_path):
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(SourceError, match="not a ROS bag"):
        open_spec(f"rosbag:{tmp_path / 'x.txt'}")
    with pytest.raises(SourceError, match="not a ROS 2 bag folder"):
        open_spec(f"rosbag:{tmp_path}")


@pytest.mark.slam
@pytest.mark.system
def test_a_bag_gives_every_frame_and_labels_like_its_tum_folder(sample_bag, tmp_path):
    out = tmp_path / "session"
    result = run_seesys("track", "--source", f"rosbag:{sample_bag}", "--mode", "rgbd", "--out", str(out))
    assert result.returncode == 0, result.stderr
    summary = summarize_session(out, SlamMode.RGBD)
    # every frame reaches SLAM; ORB-SLAM3 may lose one on a machine loaded far beyond its cores (149 seen at load 9)
    assert summary.frames == 150 and summary.frames_tracked >= 148
    frames = pd.read_csv(out / session_layout.FRAMES_CSV)
    listed = [
        float(line.split()[0])
        for line in (SAMPLE / "rgb.txt").read_text().splitlines()
        if line and not line.startswith("#")
    ]
    assert frames.timestamp.to_numpy() == pytest.approx(listed, abs=1e-6)

    labels_csv = tmp_path / "labels.csv"
    result = run_seesys("dataset", "label", str(out), "--out", str(labels_csv))
    assert result.returncode == 0, result.stderr
    from_bag = pd.read_csv(labels_csv)
    # The same session labelled against the TUM folder's own ground truth: the bag's must give the same labels.
    reference = tmp_path / "reference"
    shutil.copytree(out, reference)
    shutil.copy(SAMPLE / "groundtruth.txt", reference / session_layout.GROUND_TRUTH)
    from_tum = label_session(reference, False, load_label_config()).to_frame()
    assert len(from_tum) == 150 and (from_tum.status == "labelled").sum() >= 140
    assert list(from_bag.status) == list(from_tum.status)
    assert from_bag.error_m.to_numpy() == pytest.approx(from_tum.error_m.to_numpy(), abs=1e-9, nan_ok=True)
    assert len(read_tum(out / session_layout.GROUND_TRUTH)) == 150


def write_session(folder, frames=20):
    """A small session folder in the device's formats: 20 frames, the first 3 not tracked, estimates every 5th."""
    folder.mkdir()
    times = 1000.0 + np.arange(frames) / 30
    states = ["NOT_INITIALIZED"] * 3 + ["OK"] * (frames - 3)
    pd.DataFrame(
        {"frame_index": range(frames), "timestamp": times, "state": states, "tracked_points": 100, "track_ms": 10.0}
    ).to_csv(folder / session_layout.FRAMES_CSV, index=False)
    tum = "".join(f"{t:.6f} {0.01 * i} 0.5 {-0.02 * i} 0 0 0.6 0.8\n" for i, t in enumerate(times) if i >= 3)
    (folder / session_layout.TRAJECTORY).write_text("# timestamp tx ty tz qx qy qz qw\n" + tum)
    (folder / session_layout.GROUND_TRUTH).write_text(tum)
    ends = list(range(5, frames, 5))
    estimates = dict.fromkeys(session_layout.ESTIMATE_COLUMNS, 0.0)
    estimates.update(
        frame_index=ends,
        timestamp=times[ends],
        error_m=[0.004 * (k + 1) for k in range(len(ends))],
        model_version="deepsee-test",
    )
    pd.DataFrame(estimates).to_csv(folder / session_layout.ESTIMATES_CSV, index=False)
    # A predicted covariance for every tracked frame but frame 7 (too few points), distinct per frame.
    rows = [[i, times[i], *session_layout.covariance_row(_covariance(i))] for i in range(3, frames) if i != 7]
    pd.DataFrame(rows, columns=session_layout.POSE_COVARIANCE_COLUMNS).to_csv(
        folder / session_layout.POSE_COVARIANCE_CSV, index=False
    )
    return times


def _covariance(i: int) -> np.ndarray:
    c = np.diag([1e-6 * i, 2e-6, 3e-6, 1e-5, 2e-5, 3e-5])
    c[0, 4] = c[4, 0] = 1e-7 * i
    return c


@pytest.mark.system
def test_export_bag_writes_poses_states_and_estimates_as_a_ros2_bag(tmp_path):
    from rosbags.highlevel import AnyReader

    times = write_session(tmp_path / "s")
    out = tmp_path / "exported"
    result = run_seesys("session", "export-bag", str(tmp_path / "s"), "--out", str(out))
    assert result.returncode == 0, result.stderr
    with AnyReader([out]) as reader:
        types = {topic: info.msgtype for topic, info in reader.topics.items()}
        read = {}
        for connection, ns, raw in reader.messages():
            read.setdefault(connection.topic, []).append((ns, reader.deserialize(raw, connection.msgtype)))
    assert types == {
        "/seesys/pose": "geometry_msgs/msg/PoseStamped",
        "/seesys/path": "nav_msgs/msg/Path",
        "/seesys/pose_with_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
        "/seesys/pose_with_scaled_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
        "/seesys/ground_truth": "geometry_msgs/msg/PoseStamped",
        "/seesys/tracking_state": "std_msgs/msg/String",
        "/seesys/pose_error": "std_msgs/msg/Float64",
    }
    poses = read["/seesys/pose"]
    assert len(poses) == 17 and poses[0][0] == round(times[3] * 1e9)
    first = poses[1][1]
    assert first.header.frame_id == "world"
    assert (first.pose.position.x, first.pose.position.z, first.pose.orientation.w) == pytest.approx((0.04, -0.08, 0.8))
    assert first.header.stamp.sec + first.header.stamp.nanosec * 1e-9 == pytest.approx(times[4], abs=1e-6)
    with_covariance = read["/seesys/pose_with_covariance"]
    assert [ns for ns, _ in with_covariance] == [
        ns for k, (ns, _) in enumerate(poses) if k != 7 - 3
    ]  # the poses' times
    ninth = with_covariance[5][1]  # frame 9
    assert ninth.pose.pose.position.x == pytest.approx(0.09) and ninth.header.frame_id == "world"
    assert ninth.pose.covariance.reshape(6, 6) == pytest.approx(_covariance(9))
    # Scaled to the estimate: only frame 15's label pair (5, 15) has both covariances and poses (frame 0 is not
    # tracked, frame −5 does not exist); its covariance is frame 15's, scaled so that the pair's σ is the estimate.
    delta = load_label_config().delta_frames
    assert delta == 10
    [(ns, scaled)] = read["/seesys/pose_with_scaled_covariance"]
    assert ns == round(times[15] * 1e9) and scaled.pose.pose.position.x == pytest.approx(0.15)
    at = {i: np.array([0.01 * i, 0.5, -0.02 * i]) for i in (5, 15)}
    pair = relative_translation_covariance(_covariance(5), _covariance(15), at[5], at[15])
    factor = 0.012**2 / np.trace(pair)
    assert scaled.pose.covariance.reshape(6, 6) == pytest.approx(_covariance(15) * factor)
    assert [m.data for _, m in read["/seesys/tracking_state"]] == ["NOT_INITIALIZED"] * 3 + ["OK"] * 17
    assert len(read["/seesys/path"]) == 1 and len(read["/seesys/path"][0][1].poses) == 17
    assert [m.data for _, m in read["/seesys/pose_error"]] == pytest.approx([0.004, 0.008, 0.012])
    assert [ns for ns, _ in read["/seesys/pose_error"]] == [round(times[i] * 1e9) for i in (5, 10, 15)]
    again = run_seesys("session", "export-bag", str(tmp_path / "s"), "--out", str(out))
    assert again.returncode == 2 and "exists already" in again.stderr


@pytest.mark.system
def test_export_bag_of_a_folder_that_is_no_session_is_an_error(tmp_path):
    result = run_seesys("session", "export-bag", str(tmp_path), "--out", str(tmp_path / "b"))
    assert result.returncode == 2 and "not a session folder: no frames.csv" in result.stderr


def test_tf_ground_truth_with_several_child_frames_needs_the_camera_frame_named(tmp_path, small_tum):
    bag = write_sample_bag(small_tum, tmp_path / "tf.bag", ros1=True, tf_children=("base_link", "camera"))
    with open_spec(f"rosbag:{bag}", with_depth=False) as source:
        assert source.topics.ground_truth == "/tf"
        with pytest.raises(SourceError, match=r"several frames \(base_link, camera\).*ground_truth_child_frame"):
            source.ground_truth()
    named = with_rosbag(ground_truth_child_frame="camera")
    with open_spec(f"rosbag:{bag}", with_depth=False, config=named) as source, open_spec(f"tum:{small_tum}") as tum:
        assert np.allclose(source.ground_truth().positions, tum.ground_truth().positions)
