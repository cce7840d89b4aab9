"""A vectorised ray caster for scenes of axis-aligned textured rectangles.

Each face is intersected only inside the bounding rectangle of its on-screen projection (after clipping the face
against the near plane), so small, distant boxes cost little. Rays are generated with a z-component of 1 in the
camera frame, so the ray parameter at a hit is the z-depth itself. Textures are looked up with bilinear
filtering from the mip level that matches each pixel's footprint (no shimmering at a distance); shading is
Lambertian from the scene's point lights with a ``1 / (1 + (r / falloff)^2)`` falloff, plus ambient light.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seesys.core.camera import Intrinsics
from synth.config import CameraConfig
from synth.environments import Scene


@dataclass(frozen=True)
class RayGrid:
    """Normalised image coordinates ``(x, y)`` of every pixel centre of a camera (the rays' camera-frame x, y)."""

    lens: Intrinsics  # its pinhole part: the grid is undistorted
    near_m: float
    x: np.ndarray
    y: np.ndarray
    norm2: np.ndarray  # |(x, y, 1)|², the squared length of each pixel's ray direction

    @classmethod
    def for_camera(cls, camera: CameraConfig) -> RayGrid:
        lens = camera.lens
        u, v = np.meshgrid(np.arange(lens.width, dtype=np.float32), np.arange(lens.height, dtype=np.float32))
        x, y = (u - lens.cx) / lens.fx, (v - lens.cy) / lens.fy
        return cls(lens, camera.near_m, x, y, x * x + y * y + 1)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N×2) of camera-frame points (N×3) with z > 0."""
        z = points_cam[:, 2]
        lens = self.lens
        return np.column_stack([lens.fx * points_cam[:, 0] / z + lens.cx, lens.fy * points_cam[:, 1] / z + lens.cy])


@dataclass(frozen=True)
class Render:
    """A sharp render: linear radiance (arbitrary units, ~0.5 for a mid-grey lit surface), z-depth in metres
    (0 where a ray hit nothing) and the surface's albedo (reflectance 0..1; 0 where a ray hit nothing)."""

    radiance: np.ndarray
    depth: np.ndarray
    albedo: np.ndarray


def _clip_near(points_cam: np.ndarray, near: float) -> np.ndarray:
    """Sutherland–Hodgman clip of a convex polygon (N×3, camera frame) to z ≥ near."""
    out = []
    n = len(points_cam)
    for i in range(n):
        a, b = points_cam[i], points_cam[(i + 1) % n]
        a_in, b_in = a[2] >= near, b[2] >= near
        if a_in:
            out.append(a)
        if a_in != b_in:
            s = (near - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out)


def _screen_box(
    grid: RayGrid, corners_world: np.ndarray, rotation: np.ndarray, centre: np.ndarray
) -> tuple[slice, slice] | None:
    """The pixel rectangle covering a face, or None when the face is off screen or behind the camera."""
    clipped = _clip_near((corners_world - centre) @ rotation, grid.near_m)
    if len(clipped) == 0:
        return None
    uv = grid.project(clipped)
    u0, v0 = np.floor(uv.min(axis=0)).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + 1
    u0, v0 = max(u0, 0), max(v0, 0)
    u1, v1 = min(u1, grid.lens.width), min(v1, grid.lens.height)
    if u0 >= u1 or v0 >= v1:
        return None
    return slice(v0, v1), slice(u0, u1)


def render(scene: Scene, rotation: np.ndarray, centre: np.ndarray, grid: RayGrid) -> Render:
    """Render ``scene`` from a camera with orientation ``rotation`` (R_world_camera, 3×3, optical frame) at
    ``centre`` (camera centre in the world)."""
    r = rotation.astype(np.float32)
    dirs = [r[k, 0] * grid.x + r[k, 1] * grid.y + r[k, 2] for k in range(3)]
    with np.errstate(divide="ignore"):
        inv = [np.float32(1.0) / d for d in dirs]
    shape = (grid.lens.height, grid.lens.width)
    depth = np.full(shape, np.inf, np.float32)
    face_id = np.full(shape, -1, np.int32)
    # Per pixel, filled by the nearest face so far: texture coordinates (level-0 texels) and the footprint of
    # the pixel on the surface in texels, z·|d|² / (f · texel · |d_axis|), which picks the mip level.
    tex_u = np.zeros(shape, np.float32)
    tex_v = np.zeros(shape, np.float32)
    footprint = np.ones(shape, np.float32)
    faces = scene.faces
    for i in range(len(faces)):
        a = int(faces.axis[i])
        # Back-face culling: a face is seen only from the side it faces.
        if (centre[a] - faces.coord[i]) * faces.sign[i] <= 0:
            continue
        box = _screen_box(grid, faces.corners(i), rotation, centre)
        if box is None:
            continue
        b, c = (a + 1) % 3, (a + 2) % 3
        t = np.float32(faces.coord[i] - centre[a]) * inv[a][box]
        pb = np.float32(centre[b]) + t * dirs[b][box]
        pc = np.float32(centre[c]) + t * dirs[c][box]
        zb = depth[box]
        hit = (
            (t > grid.near_m)
            & (t < zb)
            & (pb >= faces.lo[i, b])
            & (pb <= faces.hi[i, b])
            & (pc >= faces.lo[i, c])
            & (pc <= faces.hi[i, c])
        )
        th = t[hit]
        zb[hit] = th
        face_id[box][hit] = i
        per_texel = np.float32(1.0 / faces.texel_m[i])
        tex_u[box][hit] = pb[hit] * per_texel + np.float32(faces.offset[i, 0])
        tex_v[box][hit] = pc[hit] * per_texel + np.float32(faces.offset[i, 1])
        footprint[box][hit] = (
            th * grid.norm2[box][hit] * (per_texel / np.float32(grid.lens.fx)) / np.abs(dirs[a][box][hit])
        )

    missed = face_id < 0
    fid = np.maximum(face_id, 0)
    depth[missed] = 0.0
    level = np.clip(
        np.floor(np.log2(np.maximum(footprint, 1.0)) + np.float32(0.3)), 0, scene.textures.levels - 1
    ).astype(np.int32)
    albedo = scene.textures.sample(faces.tile[fid], tex_u, tex_v, level)

    irradiance = np.full(shape, scene.ambient, np.float32)
    for light in scene.lights.astype(np.float32):
        lx, ly, lz = (light[k] - (np.float32(centre[k]) + depth * dirs[k]) for k in range(3))
        r2 = lx * lx + ly * ly + lz * lz
        # On a face, the light's offset along the normal is the same for every point.
        normal_offset = (faces.sign * (light[faces.axis] - faces.coord)).astype(np.float32)
        cosine = np.maximum(normal_offset[fid], 0.0) / np.sqrt(r2)
        irradiance += np.float32(scene.light_power) * cosine / (1.0 + r2 / np.float32(scene.falloff_m**2))
    radiance = albedo * irradiance
    radiance[missed] = 0.0
    albedo[missed] = 0.0
    return Render(radiance, depth, albedo)
