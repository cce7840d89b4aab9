"""PSD geometry and the three layers, cell by cell, on a constructed frame."""

from __future__ import annotations

import numpy as np
import pytest

from seesys.core.psd import INLIER_LAYER, KEYPOINT_LAYER, MAP_POINT_LAYER, PsdGeometry, build_psd, inverse_depth_code


@pytest.mark.parametrize(
    "size, expected",
    [((640, 480), (96, 128, 3)), ((320, 240), (48, 64, 3)), ((752, 480), (96, 152, 3)), ((1280, 720), (144, 256, 3))],
)
def test_shape_for_several_resolutions(size, expected):
    assert PsdGeometry(*size, patch_px=10, expansion=2).shape == expected


def test_paper_geometry_puts_the_image_in_the_central_block():
    g = PsdGeometry(640, 480, patch_px=10, expansion=2)
    assert (g.row_offset, g.col_offset) == (24, 32)
    cell, inside = g.cells(np.array([[0, 0], [639.9, 479.9], [-320, -240], [959.9, 719.9], [960, 100], [5, -241]]))
    rows, cols = divmod(cell, 128)
    assert list(zip(rows[inside].tolist(), cols[inside].tolist())) == [(24, 32), (71, 95), (0, 0), (95, 127)]
    assert inside.tolist() == [True, True, True, True, False, False]


def test_inverse_depth_code():
    code = inverse_depth_code(np.array([0.1, 0.5, 1.0, 2.0, 1e6]), near_depth=0.5)
    assert code.tolist() == [255, 255, 128, 64, 1]


def test_layers_on_a_constructed_frame():
    g = PsdGeometry(640, 480, patch_px=10, expansion=2)
    # Three keypoints in image cell (row 2, col 3), one in cell (0, 0), one in (47, 63); the middle one an inlier.
    keypoints = np.array([[31, 21], [35.5, 29.9], [39.9, 20], [0, 0], [639, 479]])
    responses = np.array([10.0, 20.0, 40.0, 0.2, 300.0])
    inliers = np.array([False, True, False, False, False])
    # Map points: two in one expanded cell (nearest wins), one left of the image, one beyond the frustum.
    map_uv = np.array([[100, 100], [105, 104], [-300, 50], [2000, 50]])
    map_z = np.array([2.0, 1.0, 0.25, 1.0])
    psd = build_psd(
        g,
        keypoints=keypoints,
        responses=responses,
        inliers=inliers,
        map_points_uv=map_uv,
        map_points_depth=map_z,
        near_depth=0.5,
    )
    assert psd.shape == (96, 128, 3) and psd.dtype == np.uint8

    kp = psd[:, :, KEYPOINT_LAYER]
    assert kp[24 + 2, 32 + 3] == round((10 + 20 + 40) / 3)
    assert kp[24 + 0, 32 + 0] == 1  # a cell with keypoints is never 0, however weak they are
    assert kp[24 + 47, 32 + 63] == 255  # clipped
    assert np.count_nonzero(kp) == 3

    inl = psd[:, :, INLIER_LAYER]
    assert inl[26, 35] == 255 and np.count_nonzero(inl) == 1

    mp = psd[:, :, MAP_POINT_LAYER]
    assert mp[24 + 10, 32 + 10] == 128  # depth 1.0 beats depth 2.0 in the same cell
    assert mp[24 + 5, 32 - 30] == 255  # outside the image, inside the expanded frustum
    assert np.count_nonzero(mp) == 2


def test_empty_frame_is_all_zero():
    g = PsdGeometry(64, 48, patch_px=10, expansion=2)
    psd = build_psd(
        g,
        keypoints=np.zeros((0, 2)),
        responses=np.zeros(0),
        inliers=np.zeros(0, dtype=bool),
        map_points_uv=np.zeros((0, 2)),
        map_points_depth=np.zeros(0),
        near_depth=0.5,
    )
    assert psd.shape == (10, 14, 3) and not psd.any()
