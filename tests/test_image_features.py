"""Sensor-input channels and keypoint responses against independent computations on constructed images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam_monitor.image_features import image_features, keypoint_responses


def _images() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:48, 0:64]
    checker = (((yy // 8) + (xx // 8)) % 2 * 200 + 20).astype(np.uint8)
    return {
        "noise": rng.integers(0, 256, (48, 64), dtype=np.uint8),
        "gradient": (xx * 4).astype(np.uint8),
        "checker": checker,
        "flat": np.full((48, 64), 77, dtype=np.uint8),
    }


def _laplacian_variance(img: np.ndarray) -> float:
    # 3x3 Laplacian by explicit neighbour sums on a border reflected without repeating the edge pixel.
    p = np.pad(img.astype(np.float64), 1, mode="reflect")
    lap = p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:] - 4 * p[1:-1, 1:-1]
    return float(lap.var())


def _entropy_bits(img: np.ndarray) -> float:
    _, counts = np.unique(img, return_counts=True)
    return -sum(c / img.size * math.log2(c / img.size) for c in counts)


@pytest.mark.parametrize("name", ["noise", "gradient", "checker", "flat"])
def test_sensor_channels_match_independent_computation(name):
    img = _images()[name]
    f = image_features(img)
    values = img.astype(np.float64).ravel()
    assert f.brightness == pytest.approx(values.mean() / 255, abs=1e-9)
    assert f.contrast == pytest.approx(values.std() / 255, abs=1e-6)
    assert f.entropy == pytest.approx(_entropy_bits(img), abs=1e-6)
    assert f.laplacian == pytest.approx(_laplacian_variance(img), rel=1e-5, abs=1e-6)


def test_known_values():
    half = np.zeros((10, 10), dtype=np.uint8)
    half[:, 5:] = 255
    f = image_features(half)
    assert f.brightness == pytest.approx(0.5)
    assert f.contrast == pytest.approx(0.5)
    assert f.entropy == pytest.approx(1.0)
    assert image_features(np.full((8, 8), 9, dtype=np.uint8)).laplacian == 0.0


def test_rejects_non_gray_input():
    with pytest.raises(ValueError, match="uint8 gray"):
        image_features(np.zeros((4, 4, 3), dtype=np.uint8))


def _circle_offsets() -> list[tuple[int, int]]:
    # The FAST circle from its geometric definition: the integer pixels at distance 3 (±0.2) from the centre.
    return [(dx, dy) for dx in range(-3, 4) for dy in range(-3, 4) if 2.8 <= math.hypot(dx, dy) <= 3.2]


def test_keypoint_response_is_mean_absolute_circle_difference():
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (40, 50), dtype=np.uint8)
    offsets = _circle_offsets()
    assert len(offsets) == 16
    kps = np.array([[10.2, 12.7], [25.0, 20.0], [3.0, 3.0], [46.4, 36.0]], dtype=np.float32)
    got = keypoint_responses(img, kps)
    for (x, y), r in zip(kps, got):
        cx, cy = int(round(float(x))), int(round(float(y)))
        ring = [int(img[cy + dy, cx + dx]) for dx, dy in offsets]
        assert r == pytest.approx(np.mean([abs(v - int(img[cy, cx])) for v in ring]), abs=1e-4)


def test_keypoint_response_on_constructed_corners():
    img = np.zeros((30, 30), dtype=np.uint8)
    img[10, 10] = 200  # an isolated bright dot: every circle pixel differs by 200
    img[20:, 20:] = 120  # a quadrant: its corner pixel sees 120 on the 9 circle pixels outside
    r = keypoint_responses(img, np.array([[10, 10], [5, 25], [20, 20]]))
    assert r[0] == pytest.approx(200.0)
    assert r[1] == 0.0  # flat region
    outside = sum(1 for dx, dy in _circle_offsets() if dx < 0 or dy < 0)
    assert r[2] == pytest.approx(120.0 * outside / 16)


def test_keypoints_at_the_border_and_none():
    img = np.full((12, 12), 50, dtype=np.uint8)
    assert keypoint_responses(img, np.array([[0, 0], [11.4, 11.4]])).tolist() == [0.0, 0.0]
    assert keypoint_responses(img, np.zeros((0, 2))).shape == (0,)
