"""Procedural surface textures (albedo tiles) and their mip-map pyramid.

A tile is a square albedo image that repeats over a surface. Rich tiles layer multi-scale value noise, filled
shapes, lines and printed text (the corners and blobs ORB-SLAM3 tracks); poor tiles are smooth, low-contrast
noise (plaster, paint) with a few fixtures on it (sockets, switches, frames, signs). Every tile is a pure function
of its random generator, so a scene re-renders byte-identically from its seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

_WORDS = ("EXIT", "LAB 3", "B-12", "SEESys", "No 7", "AREA", "42", "STOP", "NORTH", "ROOM", "SLAM", "A4")


def _value_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Smooth noise in [-1, 1] with about ``cells`` features along an edge, tiling seamlessly."""
    grid = rng.uniform(-1.0, 1.0, (cells, cells)).astype(np.float32)
    # Wrap-pad before the cubic resize so that the tile's opposite edges match.
    padded = np.pad(grid, 2, mode="wrap")
    step = size / cells
    big = cv2.resize(padded, (int(round(step * (cells + 4))),) * 2, interpolation=cv2.INTER_CUBIC)
    offset = int(round(2 * step))
    return big[offset : offset + size, offset : offset + size]


def _draw_shapes(rng: np.random.Generator, tile: np.ndarray, count: int, contrast: float) -> None:
    size = tile.shape[0]
    for _ in range(count):
        value = int(255 * np.clip(0.5 + contrast * rng.uniform(-0.5, 0.5), 0.0, 1.0))
        kind = rng.choice(5, p=(0.3, 0.25, 0.1, 0.2, 0.15))
        x, y = (int(v) for v in rng.integers(0, size, 2))
        extent = int(np.exp(rng.uniform(np.log(size / 128 + 2), np.log(size / 10 + 3))))
        if kind == 0:
            cv2.rectangle(tile, (x, y), (x + extent, y + int(extent * rng.uniform(0.3, 1.5))), value, -1)
        elif kind == 1:
            cv2.circle(tile, (x, y), extent // 2, value, -1, lineType=cv2.LINE_AA)
        elif kind == 2:
            x2, y2 = (int(v) for v in np.array([x, y]) + rng.integers(-2 * extent, 2 * extent + 1, 2))
            cv2.line(tile, (x, y), (x2, y2), value, int(rng.integers(1, 4)), lineType=cv2.LINE_AA)
        elif kind == 3:
            pts = rng.integers(-extent, extent, (3, 2)) + np.array([x, y])
            cv2.fillConvexPoly(tile, pts.astype(np.int32), value, lineType=cv2.LINE_AA)
        else:
            word = _WORDS[int(rng.integers(0, len(_WORDS)))]
            scale = extent / 40
            cv2.putText(tile, word, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, value, max(1, extent // 25), cv2.LINE_AA)


def make_tile(
    rng: np.random.Generator, size: int, shapes: int, contrast: float, albedo: float, poor: bool
) -> np.ndarray:
    """One albedo tile, float32 in [0, 1], mean near ``albedo``.

    A rich tile carries ``shapes`` shapes over layered noise; a poor one is bare paint with ``shapes`` fixtures.
    """
    if poor:
        tile = albedo + 0.06 * contrast * _value_noise(rng, size, 4) + 0.02 * contrast * _value_noise(rng, size, 16)
        if shapes:
            # The fixtures draw from a spawned generator: ``rng``'s own stream, and so every scene drawn after
            # the bare tiles, stays what it is without them.
            canvas = np.full((size, size), 128, np.uint8)
            _draw_shapes(rng.spawn(1)[0], canvas, shapes, contrast)
            tile += canvas.astype(np.float32) / 255 - 128 / 255
        return np.clip(tile, 0.0, 1.0).astype(np.float32)
    base = (
        0.15 * _value_noise(rng, size, 3)
        + 0.12 * _value_noise(rng, size, 12)
        + 0.1 * _value_noise(rng, size, 48)
        + 0.06 * _value_noise(rng, size, 128)
    )
    # OpenCV draws text only on 8-bit images; the shapes are drawn on an 8-bit canvas of the noise.
    canvas = np.clip(255 * (0.5 + contrast * base), 0, 255).astype(np.uint8)
    _draw_shapes(rng, canvas, shapes, contrast)
    tile = albedo + (canvas.astype(np.float32) / 255 - 0.5)
    return np.clip(tile, 0.0, 1.0).astype(np.float32)


@dataclass(frozen=True)
class TexturePyramid:
    """All tiles of a scene in one atlas image: mip level ``l`` is a column of tiles of edge ``size >> l``,
    the levels side by side. Each tile is wrap-padded by one texel so that bilinear look-ups across a tile's seam
    read the opposite edge (the tile repeats)."""

    size: int
    levels: int
    atlas: np.ndarray
    columns: tuple[int, ...]  # x offset of each level's column

    @classmethod
    def build(cls, tiles: list[np.ndarray], levels: int) -> TexturePyramid:
        size = tiles[0].shape[0]
        columns = []
        blocks = []
        x = 0
        current = tiles
        for _ in range(levels):
            block = np.concatenate([np.pad(t, 1, mode="wrap") for t in current], axis=0)
            columns.append(x)
            blocks.append(block)
            x += block.shape[1]
            current = [cv2.resize(t, (t.shape[1] // 2, t.shape[0] // 2), interpolation=cv2.INTER_AREA) for t in current]
        atlas = np.zeros((blocks[0].shape[0], x), np.float32)
        for col, block in zip(columns, blocks):
            atlas[: block.shape[0], col : col + block.shape[1]] = block
        return cls(size, levels, atlas, tuple(columns))

    def sample(self, tile: np.ndarray, u: np.ndarray, v: np.ndarray, level: np.ndarray) -> np.ndarray:
        """Bilinear albedo at texel coordinates (u, v) of level 0, in tile ``tile``, from mip level ``level``."""
        scale = np.exp2(-level.astype(np.float32))
        edge = np.float32(self.size) * scale
        x = np.mod(u * scale, edge) + 1.0 + np.asarray(self.columns, np.float32)[level]
        y = np.mod(v * scale, edge) + 1.0 + tile.astype(np.float32) * (edge + 2.0)
        return cv2.remap(
            self.atlas, x.astype(np.float32), y.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
