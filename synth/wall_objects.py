"""Objects to scan standing against a room's walls: textured boxes on the floor, placed round the room in order.

The simulated study's scanning task and the dataset's ``scan`` motion group place their objects here, so that the
dataset renders the close views of boxes before walls that the task's operators make.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synth.environments import Box, Scene, with_boxes

# Clutter boxes this close (m) to an object's corners are removed: the object stands where they stood.
OBJECT_CLEARANCE_M = 0.05


@dataclass(frozen=True)
class WallObject:
    """A box against a wall: the point to aim at (its top's centre a little below the top, world frame), the
    horizontal unit vector from it into the room (where a scanning operator stands), and the box."""

    aim: np.ndarray
    facing: np.ndarray
    box: Box

    def viewpoint(self, distance_m: float) -> np.ndarray:
        """Where to stand (x, y) to scan the object from ``distance_m`` (from the box's centre line)."""
        return self.aim[:2] + distance_m * self.facing

    def around(self, distance_m: float, angles: np.ndarray) -> np.ndarray:
        """The places (N×2, x, y) ``distance_m`` from the box's centre line at ``angles`` (radians, N) from its
        viewpoint, turning anticlockwise: where a sweep round the object passes."""
        c, s = np.cos(angles), np.sin(angles)
        f = self.facing
        return self.aim[:2] + distance_m * np.column_stack([c * f[0] - s * f[1], s * f[0] + c * f[1]])


def wall_point(angle: float, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The point of the room's walls (half extents ``half``) in direction ``angle`` from the centre, and the wall's
    inward normal."""
    direction = np.array([np.cos(angle), np.sin(angle)])
    scale = np.min(half / np.maximum(np.abs(direction), 1e-9))
    point = direction * scale
    axis = int(np.argmax(np.abs(point) / half))
    normal = np.zeros(2)
    normal[axis] = -np.sign(point[axis])
    return point, normal


def place_wall_objects(
    room: np.ndarray,
    count: int,
    size_m: tuple[float, float],
    height_m: tuple[float, float],
    wall_gap_m: float,
    rng: np.random.Generator,
    min_spacing_m: float = 0.0,
) -> list[WallObject]:
    """``count`` boxes round a room of extents ``room`` (width, depth, height; centred on the origin), in order
    round it from a random start and direction, each at a random place within a fifth of its share of the round:
    footprint ``size_m`` and height ``height_m`` drawn per box, ``wall_gap_m`` from the wall and from a corner's
    other wall. A box whose centre comes within ``min_spacing_m`` of one placed before it is left out (boxes
    crowd in the corners of small rooms, and a sweep round one would pass through its neighbour); what is drawn
    does not depend on it."""
    half = np.asarray(room[:2], float) / 2
    first = rng.uniform(0, 2 * np.pi)
    direction = rng.choice([-1.0, 1.0])
    placed: list[WallObject] = []
    for k in range(count):
        angle = first + direction * 2 * np.pi * (k + rng.uniform(-0.2, 0.2)) / count
        wall, normal = wall_point(angle, half)
        size = rng.uniform(*size_m)
        height = rng.uniform(*height_m)
        centre = wall + normal * (wall_gap_m + size / 2)
        centre = np.clip(centre, -half + wall_gap_m + size / 2, half - wall_gap_m - size / 2)
        lo = np.array([centre[0] - size / 2, centre[1] - size / 2, 0.0])
        box = Box(lo, lo + np.array([size, size, height]))
        if all(np.linalg.norm(centre - o.aim[:2]) >= min_spacing_m for o in placed):
            placed.append(WallObject(np.array([centre[0], centre[1], height - 0.05]), normal, box))
    return placed


def with_wall_objects(scene: Scene, objects: list[WallObject], rng: np.random.Generator) -> Scene:
    """``scene`` with ``objects`` added (after its own boxes, as textured clutter drawn from ``rng``), less the
    clutter boxes within :data:`OBJECT_CLEARANCE_M` of their corners: an object stands where they stood."""
    corners = np.array(
        [
            [x, y, z]
            for b in (o.box for o in objects)
            for x in (b.lo[0], b.hi[0])
            for y in (b.lo[1], b.hi[1])
            for z in (0.0, b.hi[2])
        ]
    )
    return with_boxes(scene.without_boxes_near(corners, OBJECT_CLEARANCE_M), [o.box for o in objects], rng)
