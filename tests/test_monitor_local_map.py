"""The monitor's local map: deduplication, age and size bounds, lost points."""

from __future__ import annotations

import numpy as np
import pytest
from monitor_reference import ReferenceLocalMap, same_rows

from slam_monitor.local_map import LocalMap


def test_points_seen_again_or_nudged_within_a_voxel_are_one_entry():
    m = LocalMap(voxel=0.1, max_age_frames=10, max_points=100)
    m.update(np.array([[0.01, 0.01, 0.01], [1.0, 1.0, 1.0]]), frame_index=0)
    m.update(np.array([[0.02, 0.03, 0.04], [5.0, 5.0, 5.0]]), frame_index=1)
    assert len(m) == 3
    nudged = m.points[np.argmin(np.linalg.norm(m.points, axis=1))]
    np.testing.assert_allclose(nudged, [0.02, 0.03, 0.04])  # the newest position wins
    assert sorted(m.last_seen.tolist()) == [0, 1, 1]


def test_old_points_are_forgotten_and_the_size_is_bounded():
    m = LocalMap(voxel=0.01, max_age_frames=3, max_points=4)
    for i in range(5):
        m.update(np.array([[float(i), 0.0, 0.0]]), frame_index=i)
    assert sorted(m.last_seen.tolist()) == [2, 3, 4]
    m.update(np.array([[10.0 + k, 0.0, 0.0] for k in range(3)]), frame_index=5)
    assert len(m) == 4 and sorted(m.last_seen.tolist()) == [4, 5, 5, 5]  # least recently seen dropped first


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


@pytest.mark.parametrize("seed", range(20))
def test_frames_kept_aside_merge_into_the_map_merging_every_frame_gives(seed):
    """Random frames (clears, gaps, NaN points, updates larger than the bound): the lost points after every update
    and the map whenever it is read equal the frame-by-frame reference's."""
    rng = np.random.default_rng(seed)
    voxel, max_age, max_points = 0.05, int(rng.integers(1, 10)), int(rng.integers(1, 300))
    local_map, reference = LocalMap(voxel, max_age, max_points), ReferenceLocalMap(voxel, max_age, max_points)
    read_every, frame = int(rng.integers(1, 7)), 0
    for step in range(40):
        if rng.random() < 0.05:
            local_map.clear()
            reference.clear()
        points = rng.uniform(-1, 1, (int(rng.choice([0, 2, 10, 150, 400])), 3))
        if len(points) and rng.random() < 0.2:
            points[0] = np.nan
        frame += int(rng.integers(1, 4))
        local_map.update(points, frame)
        reference.update(points, frame)
        assert same_rows(local_map.lost_points(), reference.lost_points())
        if step % read_every == 0:
            assert same_rows(
                np.column_stack([local_map.points, local_map.last_seen]),
                np.column_stack([reference.points, reference.last_seen]),
            )
