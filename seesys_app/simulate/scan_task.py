"""The scanning task of the simulated user study: a rendered room with N objects to scan in order.

Every object is a textured box standing on the floor against a wall, placed round the room by the layout seed (the
same room and objects for every participant, as in a lab). The places differ in difficulty because the room does:
an object may stand before a bare wall, in a dark corner far from the lights, or among clutter, and the same hand
motion that is harmless before a textured, well-lit wall makes SLAM fail there. Each object's region is recorded.

Clutter boxes on the way between objects are removed (the operator walks a straight line from one object's
viewpoint to the next), as the dataset's renders remove boxes on the camera path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synth.config import EnvironmentPreset, SensorConfig
from synth.environments import RICH_TILES, Scene, build_scene
from synth.wall_objects import WallObject, place_wall_objects, with_wall_objects

# Clearance (m) kept between the operator's path (walks and sweeps) and clutter boxes.
PATH_CLEARANCE_M = 0.3


@dataclass(frozen=True)
class TaskConfig:
    """``[task]`` of configs/simulate.toml."""

    environment: str
    layout_seed: int
    camera_model: str
    mode: str
    objects: int
    object_size_m: tuple[float, float]
    object_height_m: tuple[float, float]
    wall_gap_m: float
    start_offset_m: float
    settle_s: float
    max_task_s: float
    dark_light_share: float
    clutter_boxes: int
    clutter_radius_m: float


@dataclass(frozen=True)
class TaskObject(WallObject):
    """One object to scan (a box against a wall: where the operator aims and stands, :class:`WallObject`), its place
    in the scanning order, and what makes its place hard."""

    number: int  # 1, 2, ... in scanning order
    regions: tuple[str, ...]  # of "bare wall", "dark", "clutter"; empty: a textured, lit, open place
    light_share: float  # light reaching it / the best lit object's

    def record(self) -> dict:
        return {
            "object": self.number,
            "aim_m": [round(float(v), 4) for v in self.aim],
            "facing": [round(float(v), 4) for v in self.facing],
            "regions": list(self.regions),
            "light_share": round(self.light_share, 3),
        }


@dataclass(frozen=True)
class ScanTask:
    scene: Scene
    objects: tuple[TaskObject, ...]


def _light_at(scene: Scene, point: np.ndarray) -> float:
    r = np.linalg.norm(scene.lights - point, axis=1)
    return float(np.sum(1.0 / (1.0 + (r / scene.falloff_m) ** 2)))


def _bare_wall_behind(scene: Scene, point: np.ndarray, normal: np.ndarray) -> bool:
    """Whether the room wall behind ``point`` (facing ``normal``) has a bare tile."""
    faces = scene.faces
    axis = int(np.argmax(np.abs(normal)))
    for i in range(len(faces)):
        if faces.owner[i] == -1 and faces.axis[i] == axis and faces.sign[i] == np.sign(normal[axis]):
            return bool(faces.tile[i] >= RICH_TILES)
    return False


def build_scan_task(
    preset: EnvironmentPreset, sensor: SensorConfig, task: TaskConfig, scan_distance_m: float, scan_arc_deg: float
) -> ScanTask:
    """The room of ``preset`` drawn from ``task.layout_seed`` with ``task.objects`` objects round it; clutter in the
    way of the walks between viewpoints and of sweeps of ``scan_arc_deg`` at ``scan_distance_m`` (the largest the
    operators use) is removed."""
    scene = build_scene(preset, task.layout_seed, sensor)
    rng = np.random.default_rng([task.layout_seed, 0x5CA7])
    placed = place_wall_objects(
        scene.room, task.objects, task.object_size_m, task.object_height_m, task.wall_gap_m, rng
    )

    # Clear the way: the straight walks between viewpoints and the sweeps round the objects (at the device's
    # height), and the objects' own places.
    viewpoints = [o.viewpoint(scan_distance_m) for o in placed]
    path = [np.linspace(a, b, 20) for a, b in zip(viewpoints[:-1], viewpoints[1:])]
    angles = np.radians(np.linspace(-scan_arc_deg, scan_arc_deg, 9))
    path += [o.around(scan_distance_m, angles) for o in placed]
    path_xy = np.vstack(path)
    scene = scene.without_boxes_near(np.column_stack([path_xy, np.full(len(path_xy), 1.2)]), PATH_CLEARANCE_M)
    scene = with_wall_objects(scene, placed, rng)
    clutter = scene.boxes[: len(scene.boxes) - len(placed)]  # the objects come after the room's own boxes

    lights = np.array([_light_at(scene, o.aim) for o in placed])
    objects = []
    for k, (o, light) in enumerate(zip(placed, lights), start=1):
        aim, normal = o.aim, o.facing
        regions = []
        if _bare_wall_behind(scene, aim, normal):
            regions.append("bare wall")
        share = float(light / lights.max())
        if share < task.dark_light_share:
            regions.append("dark")
        near = sum(1 for b in clutter if np.linalg.norm((b.lo[:2] + b.hi[:2]) / 2 - aim[:2]) < task.clutter_radius_m)
        if near >= task.clutter_boxes:
            regions.append("clutter")
        objects.append(TaskObject(o.aim, o.facing, o.box, k, tuple(regions), share))
    return ScanTask(scene, tuple(objects))
