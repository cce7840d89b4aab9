"""The depth-quality RTS channels (slam_monitor/depth_features.py): each camera fault moves the channel it should,
by about the amount it should, and leaves the others where they were.

Measured on renders of one room (320×240, a second of a patrol, the render's true motion standing in for the
tracked one) through the ideal camera and through camera models with one fault each: depth noise growing with z²,
a misregistration of a few pixels, and every fault of the D435-like model together; plus analytic depth images for
the exact values."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from seesys.io.trajectory_files import read_tum
from slam_monitor.depth_features import DepthFeatures, DepthQuality, noise_over_z2
from slam_monitor.monitor_config import load_monitor_config
from synth.config import load_synth_config
from synth.sequence import SequenceSpec, render_sequence

WIDTH, HEIGHT, FRAMES = 320, 240, 30
NOISE = 0.0042  # the D435-like model's sigma_z / z^2 (1/m)
SHIFT = (3.0, 0.0)  # px


@pytest.fixture(scope="module")
def cfg():
    return load_monitor_config().depth


@pytest.fixture(scope="module")
def renders(tmp_path_factory) -> dict[str, list[DepthFeatures]]:
    """Each camera's channels on every frame of the same render (same room, motion and seed)."""
    synth = load_synth_config()
    ideal = synth.camera_model("ideal")
    d435 = dataclasses.asdict(synth.camera_model("d435"))
    del d435["name"]
    cameras = {
        "ideal": {},
        "noise": {"depth_noise_m_per_m2": NOISE},
        "misregistered": {"depth_misregistration_px": SHIFT},
        "d435": d435,
    }
    spec = SequenceSpec("office", "patrol", 5, frames=FRAMES, width=WIDTH, height=HEIGHT)
    lens = synth.camera.scaled(WIDTH, HEIGHT).lens
    depth_cfg = load_monitor_config().depth
    out: dict[str, list[DepthFeatures]] = {}
    for name, effects in cameras.items():
        folder = tmp_path_factory.mktemp(name)
        config = synth.seen_through("office", dataclasses.replace(ideal, name=name, **effects))
        render_sequence(spec, config, folder, processes=1, show_progress=False)
        quality, previous = DepthQuality(depth_cfg), None
        out[name] = []
        for d, g, pose in zip(
            sorted((folder / "depth").glob("*.png")),
            sorted((folder / "rgb").glob("*.png")),
            read_tum(folder / "groundtruth.txt").matrices,
        ):
            moved = np.linalg.inv(previous) @ pose if previous is not None else None
            out[name].append(
                quality.frame(
                    _depth(d, synth.camera.depth_factor), cv2.imread(str(g), cv2.IMREAD_UNCHANGED), lens, moved
                )
            )
            previous = pose
    return out


def _depth(path: Path, factor: float) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32) / factor


def _channel(features: list[DepthFeatures], name: str) -> np.ndarray:
    return np.array([getattr(f, name) for f in features])


@pytest.mark.system
def test_depth_noise_reads_the_sensors_sigma_over_z_squared_and_only_noise_moves_it(renders):
    for camera in ("noise", "d435"):
        assert np.allclose(_channel(renders[camera], "depth_noise"), NOISE, rtol=0.15), camera
    for camera in ("ideal", "misregistered"):  # 16-bit depth quantisation only: far below any real sensor
        assert (_channel(renders[camera], "depth_noise") < NOISE / 20).all(), camera


@pytest.mark.system
def test_depth_registration_reads_a_misregistration_in_focal_lengths_apart_from_the_motion(renders):
    fx = load_synth_config().camera.scaled(WIDTH, HEIGHT).lens.fx
    settled = slice(FRAMES // 4, None)  # the fit's first frames start from no misregistration
    shifted = _channel(renders["misregistered"], "depth_registration")[settled] * fx
    assert np.allclose(shifted, np.hypot(*SHIFT), atol=0.3), shifted
    for camera in ("ideal", "noise"):
        offset = _channel(renders[camera], "depth_registration")[settled] * fx
        assert (offset < 0.5).all(), (camera, offset)
    # The D435-like model's (2, 1) px misregistration, while its depth is 10 ms later than colour and its colour
    # rows are read over 20 ms: the image motion's share of the offsets is fitted away, the misregistration stays.
    d435 = _channel(renders["d435"], "depth_registration")[settled] * fx
    assert np.allclose(d435, np.hypot(2.0, 1.0), atol=0.4), d435


def _box(shift_px: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A box 1.5 m away before a wall 3 m away, and its gray image; the depth image's box ``shift_px`` right of
    the gray one's."""
    depth = np.full((HEIGHT, WIDTH), 3.0, np.float32)
    gray = np.full((HEIGHT, WIDTH), 50, np.uint8)
    depth[60:180, 80 + shift_px : 240 + shift_px] = 1.5
    gray[60:180, 80:240] = 200
    return depth, gray


def test_depth_registration_needs_tracked_motion_and_places_an_edge_to_a_fraction_of_a_pixel(cfg):
    """Without a tracked pose a frame's offsets cannot be told apart from its motion: the channel stays unknown
    until the window holds enough crossings of tracked frames; a still camera's offsets are the misregistration."""
    lens = load_synth_config().camera.scaled(WIDTH, HEIGHT).lens
    for shift in (0, 2):
        quality = DepthQuality(cfg)
        depth, gray = _box(shift)
        assert all(np.isnan(quality.frame(depth, gray, lens, None).depth_registration) for _ in range(5))
        registered = quality.frame(depth, gray, lens, np.eye(4)).depth_registration * lens.fx
        assert registered == pytest.approx(shift, abs=0.05), shift


def test_depth_holes_are_the_border_a_misregistration_uncovers(renders):
    for camera in ("ideal", "noise"):
        assert (_channel(renders[camera], "depth_holes") == 0).all(), camera
    uncovered = SHIFT[0] / WIDTH
    assert np.allclose(_channel(renders["misregistered"], "depth_holes"), uncovered, atol=1e-3)


def test_channels_without_depth_or_pose_are_unknown(renders, cfg):
    gray = np.zeros((HEIGHT, WIDTH), np.uint8)
    lens = load_synth_config().camera.scaled(WIDTH, HEIGHT).lens
    absent = DepthQuality(cfg).frame(None, gray, lens, np.eye(4))
    assert all(np.isnan(v) for v in vars(absent).values())
    # A flat wall has no depth edge to place: the registration is unknown rather than 0.
    wall = DepthQuality(cfg).frame(np.full((HEIGHT, WIDTH), 2.0, np.float32), gray, lens, np.eye(4))
    assert np.isnan(wall.depth_registration)
    assert wall.depth_holes == 0 and wall.depth_noise == 0
    holes = np.full((HEIGHT, WIDTH), 2.0, np.float32)
    holes[: HEIGHT // 2] = 0.0  # no depth, as every source writes it
    assert DepthQuality(cfg).frame(holes, gray, lens, None).depth_holes == pytest.approx(0.5)
    with pytest.raises(ValueError, match="not aligned"):
        DepthQuality(cfg).frame(holes[:-1], gray, lens, None)


def _slanted_plane(noise: float, rng: np.random.Generator) -> np.ndarray:
    """A plane 1.5–4 m away across the image, with depth noise sigma = ``noise`` · z²."""
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    z = 1.0 / (1.0 / 1.5 - (1.0 / 1.5 - 1.0 / 4.0) * u / WIDTH + 0.02 * v / HEIGHT)
    return (z + noise * z * z * rng.standard_normal(z.shape)).astype(np.float32)


def test_noise_over_z_squared_is_the_same_at_every_distance():
    rng = np.random.default_rng(3)
    depth = _slanted_plane(NOISE, rng)
    near, far = depth[:, : WIDTH // 3], depth[:, -WIDTH // 3 :]
    assert near.mean() < 2.2 < 3.0 < far.mean()
    for part in (near, far):
        assert noise_over_z2(1.0 / part[4::8, 4::8], 0.1) == pytest.approx(NOISE, rel=0.1)
    assert noise_over_z2(1.0 / _slanted_plane(0.0, rng)[4::8, 4::8], 0.1) < 1e-6  # a plane is exact
