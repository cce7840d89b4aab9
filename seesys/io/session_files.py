"""The device session's manifest (``session.json``), rewritten atomically, and the times and package versions it
records."""

from __future__ import annotations

import datetime
import json
import os
from importlib import metadata
from pathlib import Path
from typing import Any

from seesys.core.session_layout import MANIFEST

RECORDED_PACKAGES = ("seesys", "pyorbslam3", "numpy", "opencv-python-headless", "pyrealsense2", "evo", "scipy")


def utc_now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def package_versions() -> dict[str, str]:
    versions = {}
    for name in RECORDED_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def read_manifest(folder: Path) -> dict[str, Any]:
    return json.loads((folder / MANIFEST).read_text())


def update_manifest(folder: Path, **changes: Any) -> dict[str, Any]:
    """Merge ``changes`` into ``session.json`` atomically (write a temporary file, then rename it)."""
    path = folder / MANIFEST
    manifest = json.loads(path.read_text()) if path.exists() else {}
    manifest.update(changes)
    temporary = path.with_suffix(".json.tmp")
    temporary.write_text(json.dumps(manifest, indent=2, default=str) + "\n")
    os.replace(temporary, path)
    return manifest
