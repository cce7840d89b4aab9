"""Helpers of the renderer's tests: a config seen through a camera model, and the PNGs of a rendered folder."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import yaml

from synth.config import SynthConfig


def with_camera(config: SynthConfig, environment: str = "lab", **effects) -> SynthConfig:
    """The config with ``environment`` seen through a camera model with ``effects`` (all else ideal)."""
    return config.seen_through(environment, dataclasses.replace(config.camera_model("ideal"), name="test", **effects))


def png_bytes(folder: Path) -> dict[str, bytes]:
    """Every PNG under ``folder`` by its relative path."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*.png"))}


def depths(folder: Path) -> list[np.ndarray]:
    return [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((folder / "depth").glob("*.png"))]


def grays(folder: Path) -> list[np.ndarray]:
    return [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((folder / "rgb").glob("*.png"))]


def calibration(folder: Path) -> dict:
    """The rendered folder's calibration.yaml."""
    return yaml.safe_load((folder / "calibration.yaml").read_text())
