"""Procedural environments: a room of axis-aligned boxes with textured faces and point lights.

World frame: z up, floor at z = 0, the room centred on the origin in x and y (the convention of the shared
synthetic room). A scene is a list of rectangular faces, each lying in a plane ``x[axis] = coord`` and facing
``sign`` along that axis; the room's walls face inwards and the clutter boxes outwards. Everything is drawn
from one seed, so the same (preset, seed) gives the same scene in every worker process.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from synth.config import EnvironmentPreset, SensorConfig
from synth.textures import TexturePyramid, make_tile

# Tiles per scene: rich ones for clutter and textured walls, poor ones for bare walls, floor and ceiling variety.
RICH_TILES = 8
POOR_TILES = 2
# Bare paint is drawn a little lighter than printed and cluttered surfaces (relative albedo).
BARE_ALBEDO_GAIN = 1.1


@dataclass(frozen=True)
class Faces:
    """Rectangular faces as parallel arrays (one row per face).

    ``lo``/``hi`` bound the face in world coordinates (equal on the face's own axis); ``owner`` is the index of
    the clutter box a face belongs to (−1 for the room); ``texel_m`` is the size of one level-0 texel on that
    face; ``offset`` shifts the texture (in texels) so that faces sharing a tile differ.
    """

    axis: np.ndarray
    coord: np.ndarray
    sign: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    owner: np.ndarray
    tile: np.ndarray
    texel_m: np.ndarray
    offset: np.ndarray

    def __len__(self) -> int:
        return len(self.axis)

    def corners(self, index: int) -> np.ndarray:
        """The four corners of face ``index`` (4×3), in order around the rectangle."""
        a = int(self.axis[index])
        b, c = (a + 1) % 3, (a + 2) % 3
        lo, hi = self.lo[index], self.hi[index]
        pts = np.zeros((4, 3))
        pts[:, a] = self.coord[index]
        pts[:, b] = [lo[b], hi[b], hi[b], lo[b]]
        pts[:, c] = [lo[c], lo[c], hi[c], hi[c]]
        return pts

    def subset(self, keep: np.ndarray) -> Faces:
        return Faces(
            self.axis[keep],
            self.coord[keep],
            self.sign[keep],
            self.lo[keep],
            self.hi[keep],
            self.owner[keep],
            self.tile[keep],
            self.texel_m[keep],
            self.offset[keep],
        )


@dataclass(frozen=True)
class Box:
    """An axis-aligned clutter box (lo, hi corners in metres)."""

    lo: np.ndarray
    hi: np.ndarray


@dataclass(frozen=True)
class Scene:
    preset: EnvironmentPreset
    seed: int
    room: np.ndarray  # (3,) width, depth, height
    boxes: tuple[Box, ...]
    faces: Faces
    textures: TexturePyramid
    lights: np.ndarray  # (L, 3) point-light positions
    light_power: float
    falloff_m: float
    ambient: float

    def room_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        w, d, h = self.room
        return np.array([-w / 2, -d / 2, 0.0]), np.array([w / 2, d / 2, h])

    def without_boxes_near(self, points: np.ndarray, clearance: float) -> Scene:
        """The scene minus the boxes that come within ``clearance`` of any of ``points`` (the camera path)."""
        removed = [i for i, b in enumerate(self.boxes) if _distance_to_box(points, b).min() <= clearance]
        if not removed:
            return self
        faces = self.faces.subset(~np.isin(self.faces.owner, removed))
        boxes = tuple(b for i, b in enumerate(self.boxes) if i not in removed)
        return Scene(
            self.preset,
            self.seed,
            self.room,
            boxes,
            faces,
            self.textures,
            self.lights,
            self.light_power,
            self.falloff_m,
            self.ambient,
        )


def _distance_to_box(points: np.ndarray, box: Box) -> np.ndarray:
    gap = np.maximum(np.maximum(box.lo - points, points - box.hi), 0.0)
    return np.linalg.norm(gap, axis=1)


def _box_faces(lo: np.ndarray, hi: np.ndarray, inward: bool) -> list[tuple[int, float, int, np.ndarray, np.ndarray]]:
    """The faces of a box as (axis, coord, sign, lo, hi); inward for the room, outward for clutter."""
    faces = []
    for axis in range(3):
        for at_hi in (False, True):
            coord = hi[axis] if at_hi else lo[axis]
            outward = 1 if at_hi else -1
            if not inward and axis == 2 and not at_hi:
                continue  # a clutter box's bottom rests on the floor and is never seen
            flo, fhi = lo.copy(), hi.copy()
            flo[axis] = fhi[axis] = coord
            faces.append((axis, float(coord), -outward if inward else outward, flo, fhi))
    return faces


def _place_boxes(rng: np.random.Generator, preset: EnvironmentPreset, room: np.ndarray) -> list[Box]:
    w, d, h = room
    boxes = []
    for _ in range(preset.boxes):
        size = rng.uniform(*preset.box_m, 3)
        size[2] = min(size[2] * rng.uniform(0.6, 1.8), h * 0.8)
        # Half of the clutter stands along the walls (shelves, cabinets), the rest anywhere on the floor.
        centre = np.array([rng.uniform(-w / 2, w / 2), rng.uniform(-d / 2, d / 2)])
        if rng.uniform() < 0.5:
            wall_axis = int(rng.integers(0, 2))
            half = room[wall_axis] / 2 - size[wall_axis] / 2
            centre[wall_axis] = half if rng.uniform() < 0.5 else -half
        centre = np.clip(centre, -room[:2] / 2 + size[:2] / 2, room[:2] / 2 - size[:2] / 2)
        lo = np.array([centre[0] - size[0] / 2, centre[1] - size[1] / 2, 0.0])
        boxes.append(Box(lo, lo + size))
    return boxes


def _faces(rows: list, tile: np.ndarray, texel_m: float, size: int, rng: np.random.Generator) -> Faces:
    """Faces of ``rows`` (owner, (axis, coord, sign, lo, hi)) with their tiles; texel sizes vary ±(0.7–1.4)× around
    ``texel_m`` and textures are offset at random, drawn from ``rng``."""
    return Faces(
        axis=np.array([f[0] for _, f in rows], np.int64),
        coord=np.array([f[1] for _, f in rows]),
        sign=np.array([f[2] for _, f in rows], np.float64),
        lo=np.array([f[3] for _, f in rows]),
        hi=np.array([f[4] for _, f in rows]),
        owner=np.array([o for o, _ in rows], np.int64),
        tile=tile,
        texel_m=texel_m * rng.uniform(0.7, 1.4, len(rows)),
        offset=rng.uniform(0, size, (len(rows), 2)),
    )


def build_scene(preset: EnvironmentPreset, seed: int, sensor: SensorConfig) -> Scene:
    """The scene of ``preset`` drawn from ``seed``: room, clutter, textures and lights."""
    rng = np.random.default_rng([seed, 0x5EE5])
    room = np.array(preset.room_m, np.float64)
    size = sensor.texture_size
    shapes = max(1, int(round(preset.texture_density * preset.texture_scale_m**2)))
    fixtures = int(round(preset.bare_fixture_density * preset.texture_scale_m**2))
    spread = preset.albedo_spread
    tiles = [
        make_tile(
            rng, size, shapes, preset.texture_contrast, preset.albedo * rng.uniform(1 - spread, 1 + spread), False
        )
        for _ in range(RICH_TILES)
    ]
    tiles += [
        make_tile(
            rng,
            size,
            fixtures,
            preset.texture_contrast,
            preset.albedo * rng.uniform(BARE_ALBEDO_GAIN - spread, BARE_ALBEDO_GAIN + spread),
            True,
        )
        for _ in range(POOR_TILES)
    ]
    textures = TexturePyramid.build(tiles, sensor.texture_levels)
    boxes = _place_boxes(rng, preset, room)

    lo, hi = np.array([-room[0] / 2, -room[1] / 2, 0.0]), np.array([room[0] / 2, room[1] / 2, room[2]])
    rows = [(-1, f) for f in _box_faces(lo, hi, inward=True)]
    for owner, box in enumerate(boxes):
        rows += [(owner, f) for f in _box_faces(box.lo, box.hi, inward=False)]
    # ``poor_walls`` of the 4 side walls (drawn at random), the floor and ceiling when ``bare_floor_ceiling``,
    # and a ``poor_boxes`` share of the clutter get bare tiles; everything else is textured.
    side_walls = [i for i, (_, f) in enumerate(rows[:6]) if f[0] != 2]
    poor = set(rng.permutation(side_walls)[: preset.poor_walls].tolist())
    if preset.bare_floor_ceiling:
        poor |= {i for i, (_, f) in enumerate(rows[:6]) if f[0] == 2}
    poor_owners = {b for b in range(len(boxes)) if rng.uniform() < preset.poor_boxes}
    poor |= {i for i, (owner, _) in enumerate(rows) if owner in poor_owners}
    tile = np.array(
        [
            RICH_TILES + rng.integers(0, POOR_TILES) if i in poor else rng.integers(0, RICH_TILES)
            for i in range(len(rows))
        ],
        np.int64,
    )
    faces = _faces(rows, tile, preset.texture_scale_m / size, size, rng)

    n_lights = 1 if room[0] * room[1] < 40 else 2
    lights = np.column_stack(
        [
            rng.uniform(-room[0] / 4, room[0] / 4, n_lights),
            rng.uniform(-room[1] / 4, room[1] / 4, n_lights),
            np.full(n_lights, room[2] - 0.3),
        ]
    )
    return Scene(
        preset, seed, room, tuple(boxes), faces, textures, lights, preset.light, preset.falloff_m, preset.ambient
    )


def with_boxes(scene: Scene, boxes: list[Box], rng: np.random.Generator) -> Scene:
    """``scene`` with ``boxes`` added as textured clutter (rich tiles; the scanning task's objects)."""
    faces = scene.faces
    rows = [(len(scene.boxes) + k, f) for k, box in enumerate(boxes) for f in _box_faces(box.lo, box.hi, inward=False)]
    size = scene.textures.size
    added = _faces(
        rows, rng.integers(0, RICH_TILES, len(rows)).astype(np.int64), scene.preset.texture_scale_m / size, size, rng
    )
    merged = Faces(
        *(
            np.concatenate([getattr(faces, name), getattr(added, name)])
            for name in ("axis", "coord", "sign", "lo", "hi", "owner", "tile", "texel_m", "offset")
        )
    )
    return dataclasses.replace(scene, boxes=scene.boxes + tuple(boxes), faces=merged)
