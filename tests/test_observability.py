"""The observability, residual and second-opinion computations against cases with a known answer: the predicted σ
of a point set matches a Monte-Carlo of the pose fit, a planar or one-sided point set is ill-conditioned, a perturbed
pose raises the residuals, a rolling shutter's shear is read and a pose error is not, and the flow's motion on the
sample's frames agrees with the renderer's ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from testkit.sample import SAMPLE, sample_frames

from seesys.core.pose_covariance import pair_covariance, relative_translation_covariance, scaled_to_error
from seesys.io.trajectory_files import read_tum
from slam_monitor.observability import (
    NoiseModel,
    coverage,
    depth_spread,
    pose_covariance_world,
    pose_information,
    pose_observability,
    residual_channels,
    residual_shear,
    translation_observability,
)
from slam_monitor.second_opinion import (
    FlowConfig,
    SecondOpinion,
    keypoint_depths,
    relative_translation_error,
    rgbd_motion,
)
from slam_monitor.slam_features import project

NOISE = NoiseModel(pixel_sigma_px=1.0, depth_sigma_at_1m_m=0.004, coverage_grid=4)
K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
FLOW = FlowConfig(5, 10, 150, 15, 3, 1.0, 0.2, 8.0)


def _points(rng, n=150, spread=1.5, near=1.5, far=4.0) -> np.ndarray:
    z = rng.uniform(near, far, n)
    return np.column_stack([rng.uniform(-spread, spread, n) * z / 3, rng.uniform(-spread, spread, n) * z / 4, z])


def _moved(points: np.ndarray, params: np.ndarray) -> np.ndarray:
    """The points seen from a camera moved by params[:3] (camera axes) and turned by params[3:]."""
    return (points - params[:3]) @ Rotation.from_rotvec(params[3:]).as_matrix()


def _fit(points, observed_uv, observed_z=None) -> np.ndarray:
    def residuals(params):
        p = _moved(points, params)
        r = [(project(p, K) - observed_uv).ravel() / NOISE.pixel_sigma_px]
        if observed_z is not None:
            r.append((p[:, 2] - observed_z) / (NOISE.depth_sigma_at_1m_m * points[:, 2] ** 2))
        return np.concatenate(r)

    return least_squares(residuals, np.zeros(6), method="lm").x


@pytest.mark.parametrize("depth", [False, True])
def test_the_predicted_translation_sigma_matches_a_monte_carlo_of_the_pose_fit(depth):
    rng = np.random.default_rng(11)
    points = _points(rng)
    sigma, _, _ = translation_observability(pose_information(points, K[0, 0], K[1, 1], NOISE, depth))
    truth = project(points, K)
    fitted = []
    for _ in range(300):
        uv = truth + rng.normal(0, NOISE.pixel_sigma_px, truth.shape)
        z = points[:, 2] + rng.normal(0, NOISE.depth_sigma_at_1m_m * points[:, 2] ** 2) if depth else None
        fitted.append(_fit(points, uv, z)[:3])
    measured = float(np.sqrt(np.trace(np.cov(np.array(fitted).T))))
    assert measured == pytest.approx(sigma, rel=0.10)


def test_the_world_axes_covariance_matches_a_monte_carlo_of_the_fitted_camera_pose():
    """A camera turned and placed in a room: the fits' world positions and fixed-axis rotation vectors (ROS's
    convention) scatter as the covariance says, blocks and cross terms."""
    rng = np.random.default_rng(17)
    points_c = _points(rng)
    rotation_wc = Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix()
    covariance = pose_covariance_world(pose_information(points_c, K[0, 0], K[1, 1], NOISE, True), rotation_wc)
    truth = project(points_c, K)
    world = []
    for _ in range(300):
        uv = truth + rng.normal(0, NOISE.pixel_sigma_px, truth.shape)
        z = points_c[:, 2] + rng.normal(0, NOISE.depth_sigma_at_1m_m * points_c[:, 2] ** 2)
        fit = _fit(points_c, uv, z)  # camera-axes δc, δθ (R' = R exp(δθ))
        turned = Rotation.from_matrix(rotation_wc @ Rotation.from_rotvec(fit[3:]).as_matrix() @ rotation_wc.T)
        world.append(np.concatenate([rotation_wc @ fit[:3], turned.as_rotvec()]))
    measured = np.cov(np.array(world).T)
    for block in (slice(0, 3), slice(3, 6)):
        assert np.trace(measured[block, block]) == pytest.approx(np.trace(covariance[block, block]), rel=0.10)
    # every entry within 15 % of the diagonal's scale: the axes and the cross terms, not only the total
    scale = np.sqrt(np.outer(np.diag(covariance), np.diag(covariance)))
    assert np.abs(measured - covariance).max() / scale.max() < 0.15


def test_the_relative_translation_covariance_matches_a_monte_carlo_of_two_perturbed_poses():
    rng = np.random.default_rng(23)
    a = rng.normal(size=(6, 6))
    b = rng.normal(size=(6, 6))
    cov_i, cov_j = a @ a.T * 1e-6, b @ b.T * 1e-6
    pose_i = (Rotation.from_rotvec([0.2, 0.5, -0.1]).as_matrix(), np.array([1.0, 2.0, 0.5]))
    pose_j = (Rotation.from_rotvec([0.25, 0.4, 0.0]).as_matrix(), np.array([1.3, 1.8, 0.7]))

    def relative(ri, ci, cj):
        return ri.T @ (cj - ci)

    exact = relative(pose_i[0], pose_i[1], pose_j[1])
    errors = []
    for _ in range(20000):
        xi, xj = rng.multivariate_normal(np.zeros(6), cov_i), rng.multivariate_normal(np.zeros(6), cov_j)
        ri = Rotation.from_rotvec(xi[3:]).as_matrix() @ pose_i[0]  # fixed (world) axes
        errors.append(relative(ri, pose_i[1] + xi[:3], pose_j[1] + xj[:3]) - exact)
    predicted = relative_translation_covariance(cov_i, cov_j, pose_i[1], pose_j[1])
    measured = np.mean(np.sum(np.array(errors) ** 2, axis=1))
    assert measured == pytest.approx(np.trace(predicted), rel=0.05)


def test_a_covariance_scaled_to_an_estimate_keeps_its_shape_and_gives_its_pair_the_estimated_sigma():
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    covariances = {0: a @ a.T * 1e-6, 10: b @ b.T * 1e-6}
    positions = {0: np.array([0.0, 0.0, 0.0]), 10: np.array([0.05, -0.02, 0.1])}
    pair = pair_covariance(covariances, positions, 10, 10)
    assert pair is not None and pair_covariance(covariances, positions, 10, 5) is None  # frame 5 has none
    scaled = scaled_to_error(covariances[10], pair, 0.007)
    assert scaled is not None
    factor = scaled[0, 0] / covariances[10][0, 0]
    assert scaled == pytest.approx(covariances[10] * factor)  # the shape is the geometry's
    # both frames scaled alike: the label pair's σ is the estimate
    both = {k: c * factor for k, c in covariances.items()}
    assert np.sqrt(np.trace(pair_covariance(both, positions, 10, 10))) == pytest.approx(0.007)
    for nothing in (0.0, float("nan"), -0.01):
        assert scaled_to_error(covariances[10], pair, nothing) is None
    assert scaled_to_error(covariances[10], np.zeros((3, 3)), 0.007) is None


def test_a_far_one_sided_patch_is_ill_conditioned_and_a_spread_room_is_not():
    rng = np.random.default_rng(3)
    room = _points(rng)
    patch = np.column_stack([rng.uniform(0.3, 0.5, 150), rng.uniform(0.1, 0.3, 150), np.full(150, 4.0)])
    spread = translation_observability(pose_information(room, K[0, 0], K[1, 1], NOISE))
    planar = translation_observability(pose_information(patch, K[0, 0], K[1, 1], NOISE))
    assert planar[2] > 20 * spread[2]  # condition number
    assert planar[1] < spread[1] / 20  # the weakest direction
    assert planar[0] > 5 * spread[0]  # the predicted σ


def test_a_perturbed_pose_raises_the_residual_channels():
    rng = np.random.default_rng(5)
    points = _points(rng)
    keypoints = project(points, K) + rng.normal(0, 0.5, (len(points), 2))
    right = np.linalg.norm(project(points, K) - keypoints, axis=1)
    wrong_residuals = project(_moved(points, np.array([0.01, 0, 0, 0, 0.004, 0])), K) - keypoints
    wrong = np.linalg.norm(wrong_residuals, axis=1)
    good, bad = residual_channels(right, 1.0), residual_channels(wrong, 1.0)
    assert bad[0] > 2 * good[0] and bad[1] > 2 * good[1] and bad[2] > good[2] + 0.3
    channels = pose_observability(points, keypoints, wrong_residuals, K, 640, 480, NOISE, depth_measured=True)
    assert channels.residual_median_px == pytest.approx(bad[0]) and channels.translation_sigma_m > 0


def _rolling_shutter_keypoints(points, yaw_rate, pitch_rate, readout_s, rng, noise_px=0.5):
    """Where a rolling-shutter camera turning at (yaw, pitch) rad/s sees ``points``: row v is read
    readout·(v/H − 1/2) after the middle row, when the camera has turned by rate × that time."""
    uv = project(points, K)
    offset = readout_s * (uv[:, 1] / 480 - 0.5)
    turned = np.column_stack([uv[:, 0] - K[0, 0] * yaw_rate * offset, uv[:, 1] - K[1, 1] * pitch_rate * offset])
    return turned + rng.normal(0, noise_px, uv.shape)


def test_the_residual_shear_reads_a_rolling_shutter_and_not_a_pose_error():
    rng = np.random.default_rng(13)
    points = _points(rng, n=300)
    exact = project(points, K)
    # A camera turning sideways at 1 rad/s through a 20 ms readout: x moves by f·ω·T = 10.5 px from the first row
    # to the last; the pose fit would take up the rotation half, and the channel reads the other half.
    keypoints = _rolling_shutter_keypoints(points, 1.0, 0.0, 0.020, rng)
    shift_over_height = K[0, 0] * 1.0 * 0.020
    assert residual_shear(keypoints, exact - keypoints, 640, 480) == pytest.approx(shift_over_height / 2, rel=0.1)
    # Tilting: the image stretched vertically by the same amount; the fit takes up the scale half.
    keypoints = _rolling_shutter_keypoints(points, 0.0, 1.0, 0.020, rng)
    assert residual_shear(keypoints, exact - keypoints, 640, 480) == pytest.approx(shift_over_height / 2, rel=0.1)
    # A global shutter with the pose 1 cm and 0.5° wrong (residuals of several pixels): no shear beyond the noise,
    # as for the exact pose.
    keypoints = exact + rng.normal(0, 0.5, exact.shape)
    moved = project(_moved(points, np.array([0.01, 0.0, 0.0, 0.0, 0.0, 0.009])), K)
    assert np.median(np.linalg.norm(moved - keypoints, axis=1)) > 2.0
    assert residual_shear(keypoints, moved - keypoints, 640, 480) < 0.1 * shift_over_height / 2
    assert residual_shear(keypoints, exact - keypoints, 640, 480) < 0.1 * shift_over_height / 2
    # Too few points, or all on one row: no value.
    assert np.isnan(residual_shear(keypoints[:11], (exact - keypoints)[:11], 640, 480))
    one_row = np.column_stack([np.linspace(10, 600, 50), np.full(50, 240.0)])
    assert np.isnan(residual_shear(one_row, np.zeros((50, 2)), 640, 480))


def test_coverage_and_depth_spread_read_as_they_say():
    assert coverage(np.array([[10, 10], [630, 470]]), 640, 480, 4) == pytest.approx(2 / 16)
    grid = np.array([[x, y] for x in range(40, 640, 160) for y in range(30, 480, 120)])
    assert coverage(grid, 640, 480, 4) == 1.0
    assert depth_spread(np.full(20, 2.0)) == 0.0 and depth_spread(np.linspace(1, 3, 21)) == pytest.approx(0.8)
    assert np.isnan(
        pose_observability(np.ones((2, 3)), np.ones((2, 2)), np.ones((2, 2)), K, 640, 480, NOISE, False).image_coverage
    )


def test_the_residual_percentiles_and_depth_spread_are_numpys_to_the_last_bit():
    rng = np.random.default_rng(11)
    for n in [1, 2, 3, 4, 5, 9, 10, 11, 99, 100, 101, *rng.integers(3, 2000, 200)]:
        for values in (rng.lognormal(0.0, 1.0, n), rng.integers(1, 5, n).astype(float), rng.uniform(0.3, 8.0, n)):
            median, p90 = np.percentile(values, [50, 90])
            assert residual_channels(values, 1.0)[:2] == (median, p90)
            if n >= 3:
                p10, p50, p90 = np.percentile(values, [10, 50, 90])
                assert depth_spread(values) == (p90 - p10) / p50


def _orb_keypoints(gray: np.ndarray) -> np.ndarray:
    """ORB keypoints of an image, as ORB-SLAM3 hands the monitor its own (N, 2 pixels)."""
    return np.array([k.pt for k in cv2.ORB_create(1000).detect(gray, None)])


def test_the_flows_motion_on_the_samples_frames_agrees_with_the_rendered_ground_truth():
    """The renderer's exact poses: a hop's motion within 3 mm, and over the label's 10 frames (two hops of 5) the
    composed flow disagrees with the ground truth by less than 1 cm (the flow's own noise), held until the next hop
    frame, whereas a pose 3 cm off is seen."""
    frames = sample_frames(12)
    truth = read_tum(SAMPLE / "groundtruth.txt")
    poses = []
    for f in frames:
        i = int(np.argmin(np.abs(truth.timestamps - f.timestamp)))
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_quat(truth.quaternions_xyzw[i]).as_matrix()
        pose[:3, 3] = truth.positions[i]
        poses.append(pose)
    k = frames[0].intrinsics.matrix()
    keypoints = [_orb_keypoints(f.gray) for f in frames]
    step = rgbd_motion(
        frames[0].gray, frames[5].gray, keypoints[0], keypoint_depths(keypoints[0], frames[0].depth), k, FLOW
    )
    assert step is not None
    assert relative_translation_error(np.linalg.inv(poses[0]) @ poses[5], step) < 0.003

    def said(poses_wc: list[np.ndarray]) -> list[float | None]:
        opinion = SecondOpinion(FLOW)
        return [
            opinion.update(n, f.gray, f.depth, kp, k, p)
            for n, (f, kp, p) in enumerate(zip(frames, keypoints, poses_wc))
        ]

    honest = said(poses)
    assert honest[:10] == [None] * 10 and honest[10] is not None and honest[10] < 0.01
    assert honest[11] == honest[10]  # held until the next hop frame
    shifted = poses[10].copy()
    shifted[:3, 3] += np.array([0.03, 0.0, 0.0])
    off = said(poses[:10] + [shifted, poses[11]])
    assert off[10] is not None and off[10] > 0.02
    # An untracked frame breaks the span: no value until it is whole again.
    assert said(poses[:7] + [None] + poses[8:])[10:] == [None, None]
