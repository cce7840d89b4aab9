"""The monitor's local map: deduplication, age and size bounds, lost points."""

from __future__ import annotations

import numpy as np
import pytest

from slam_monitor.local_map import LocalMap


def test_points_seen_again_or_nudged_within_a_voxel_are_one_entry():
    m = LocalMap(voxel=0.1, max_age_frames=10, max_points=100)
    m.update(np.array([[0.01, 0.01, 0.01], [1.0, 1.0, 1.0]]), frame_index=0)
    m.update(np.array([[0.02, 0.03, 0.04], [5.0, 5.0, 5.0]]), frame_index=1)
    assert len(m) == 3
    nudged = m.points[np.argmin(np.linalg.norm(m.points, axis=1))]
    np.testing.assert_allclose(nudged, [0.02, 0.03, 0.04])     # the newest position wins
    assert sorted(m.last_seen.tolist()) == [0, 1, 1]


def test_old_points_are_forgotten_and_the_size_is_bounded():
    m = LocalMap(voxel=0.01, max_age_frames=3, max_points=4)
    for i in range(5):
        m.update(np.array([[float(i), 0.0, 0.0]]), frame_index=i)
    assert sorted(m.last_seen.tolist()) == [2, 3, 4]
    m.update(np.array([[10.0 + k, 0.0, 0.0] for k in range(3)]), frame_index=5)
    assert len(m) == 4 and sorted(m.last_seen.tolist()) == [4, 5, 5, 5]   # least recently seen dropped first


def test_lost_points_are_those_of_the_previous_update_only():
    m = LocalMap(voxel=0.01, max_age_frames=30, max_points=100)
    assert len(m.lost_points()) == 0
    m.update(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]), frame_index=7)
    m.update(np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 0.0]]), frame_index=9)
    np.testing.assert_allclose(m.lost_points(), [[0.0, 0.0, 2.0]])
    m.clear()
    assert len(m) == 0 and len(m.lost_points()) == 0


def test_rejects_bad_bounds():
    with pytest.raises(ValueError):
        LocalMap(voxel=0.0, max_age_frames=1, max_points=1)
