"""Relative motion signs on synthetic motions, and inlier recovery / depth / reprojection / outlier proxy on a
constructed scene with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slam_monitor.slam_features import RelativeMotion, relative_motion, slam_features

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def pose(rotation: np.ndarray, centre) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = centre
    return t


def about(axis: str, angle: float) -> np.ndarray:
    return Rotation.from_euler(axis, angle).as_matrix()


BASE = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
CHANNEL_OF_AXIS = {"x": "pitch", "y": "yaw", "z": "roll"}


@pytest.mark.parametrize("angle", [0.05, -0.05, 0.3, -0.3, -2.5])
@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_rotation_about_each_camera_axis_keeps_its_sign(axis, angle):
    before = pose(BASE, [1.0, 2.0, 3.0])
    after = pose(BASE @ about(axis, angle), [1.0, 2.0, 3.0])
    m = relative_motion(before, after)
    values = {"roll": m.roll, "pitch": m.pitch, "yaw": m.yaw}
    assert values.pop(CHANNEL_OF_AXIS[axis]) == pytest.approx(angle, abs=1e-9)
    assert all(v == pytest.approx(0.0, abs=1e-9) for v in values.values())
    np.testing.assert_allclose(m.translation, 0.0, atol=1e-12)


def _project(pose_wc: np.ndarray, point_w) -> np.ndarray:
    pc = np.linalg.inv(pose_wc) @ np.append(point_w, 1.0)
    return (K @ pc[:3])[:2] / pc[2]


@pytest.mark.parametrize("angle", [0.1, -0.1])
def test_rotation_signs_agree_with_image_motion(angle):
    """Positive yaw turns the camera right (the scene moves left in the image), positive pitch turns it up (the
    scene moves down), positive roll turns x towards y (a point right of centre moves up)."""
    start = pose(np.eye(3), [0.0, 0.0, 0.0])
    ahead, right = np.array([0.0, 0.0, 5.0]), np.array([1.0, 0.0, 5.0])
    for axis, point, pixel_axis, direction in [("y", ahead, 0, -1), ("x", ahead, 1, +1), ("z", right, 1, -1)]:
        moved = pose(about(axis, angle), [0.0, 0.0, 0.0])
        shift = _project(moved, point)[pixel_axis] - _project(start, point)[pixel_axis]
        m = relative_motion(start, moved)
        channel = {"x": m.pitch, "y": m.yaw, "z": m.roll}[axis]
        assert np.sign(shift) == direction * np.sign(channel), axis


def test_translation_is_the_displacement_in_the_current_camera():
    step = np.array([0.02, -0.01, 0.1])  # right, up, forward in the camera's own axes
    before = pose(BASE, [1.0, 2.0, 3.0])
    after = pose(BASE @ about("y", 0.2), np.array([1.0, 2.0, 3.0]) + BASE @ about("y", 0.2) @ step)
    np.testing.assert_allclose(relative_motion(before, after).translation, step, atol=1e-12)


def test_still_motion_is_zero():
    m = RelativeMotion.still()
    assert (m.roll, m.pitch, m.yaw) == (0.0, 0.0, 0.0) and not m.translation.any()


@pytest.fixture
def scene():
    """A camera and points on a 16 px pixel grid (so every match is unambiguous): 200 matched map points with
    keypoints at their projections (+ known noise), 40 lost points with a keypoint where they project, 25 lost
    points without one, 10 lost points behind the camera, and distractor keypoints between grid nodes."""
    rng = np.random.default_rng(11)
    pose_wc = pose(BASE, [0.5, -0.3, 1.2])
    nodes = np.stack(np.meshgrid(np.arange(24, W - 16, 16), np.arange(24, H - 16, 16)), axis=-1).reshape(-1, 2)
    nodes = rng.permutation(nodes)[:265] + rng.uniform(-2, 2, (265, 2))
    depth = rng.uniform(1.0, 4.0, 265)
    pc = np.column_stack([(nodes[:, 0] - K[0, 2]) * depth / K[0, 0], (nodes[:, 1] - K[1, 2]) * depth / K[1, 1], depth])
    points_w = pc @ pose_wc[:3, :3].T + pose_wc[:3, 3]
    behind_w = (
        np.column_stack([rng.uniform(-1, 1, 10), rng.uniform(-1, 1, 10), -rng.uniform(1, 3, 10)]) @ pose_wc[:3, :3].T
        + pose_wc[:3, 3]
    )
    noise = rng.uniform(-0.5, 0.5, (200, 2))
    distractors = rng.permutation(nodes + 8.0)[:150]
    keypoints = np.vstack([nodes[:200] + noise, nodes[200:240] + rng.uniform(-1, 1, (40, 2)), distractors])
    return {
        "pose_wc": pose_wc,
        "keypoints": keypoints.astype(np.float32),
        "matched_w": points_w[:200].astype(np.float32),
        "noise": noise,
        "depth": depth[:200],
        "lost_w": np.vstack([points_w[200:], behind_w]),
    }


def test_features_of_a_constructed_scene(scene):
    f = slam_features(
        pose_cw=np.linalg.inv(scene["pose_wc"]),
        motion=RelativeMotion.still(),
        matched_inliers=200,
        keypoints=scene["keypoints"],
        matched_points_w=scene["matched_w"],
        lost_points_w=scene["lost_w"],
        camera_matrix=K,
        width=W,
        height=H,
        match_gate_px=3.0,
        min_depth=0.01,
    )
    expected_inliers = np.zeros(len(scene["keypoints"]), dtype=bool)
    expected_inliers[:200] = True
    np.testing.assert_array_equal(f.inlier_keypoints, expected_inliers)
    assert f.reprojection_error_px == pytest.approx(np.linalg.norm(scene["noise"], axis=1).mean(), abs=1e-3)
    assert f.avg_mp_depth == pytest.approx(scene["depth"].mean(), rel=1e-5)
    assert f.var_mp_depth == pytest.approx(scene["depth"].var(), rel=1e-4)
    assert f.outliers == 40  # lost points behind the camera or with no keypoint do not count
    assert f.matched_inliers == 200 and f.matches_before_po == 240


def test_no_keypoints_and_no_points():
    f = slam_features(
        pose_cw=np.eye(4),
        motion=RelativeMotion.still(),
        matched_inliers=0,
        keypoints=np.zeros((0, 2)),
        matched_points_w=np.zeros((0, 3)),
        lost_points_w=np.zeros((0, 3)),
        camera_matrix=K,
        width=W,
        height=H,
        match_gate_px=3.0,
        min_depth=0.01,
    )
    assert f.outliers == 0 and np.isnan(f.avg_mp_depth) and np.isnan(f.reprojection_error_px)
