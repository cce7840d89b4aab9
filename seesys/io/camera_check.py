"""The camera scale of recorded device sessions against their ground truth (:mod:`seesys.core.camera_scale`),
with the correction each session was recorded with (``session.json``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from seesys.core import session_layout
from seesys.core.camera_scale import ScaleCheckError, ScaleFit, ScaleSettings, describe, window_scales
from seesys.core.labels import LabelError, tracked_states
from seesys.io.config import ConfigSet, build
from seesys.io.session_files import read_manifest
from seesys.io.session_labels import read_session_track


@dataclass(frozen=True)
class SessionScale:
    folder: Path
    fit: ScaleFit
    applied_correction: float  # the depth_correction the device applied while recording
    source: str  # the session's frame source as recorded (KIND:PATH)


def load_scale_settings(directory: Path | None = None) -> ScaleSettings:
    """``[scale]`` of ``configs/camera.toml``."""
    configs = ConfigSet.read(directory)
    return build(ScaleSettings, dict(configs.data("camera").get("scale", {})), f"{configs.path('camera')} [scale]")


def _manifest(folder: Path) -> dict:
    try:
        return read_manifest(folder)
    except (OSError, json.JSONDecodeError) as e:
        raise ScaleCheckError(f"cannot read {folder / session_layout.MANIFEST}: {e}") from None


def session_scale(folder: Path, settings: ScaleSettings, association_max_dt_s: float) -> SessionScale:
    """The camera scale of one RGB-D session folder with ground truth; :class:`ScaleCheckError` naming the
    session when it is monocular, has no ground truth or too little tracked motion."""
    manifest = _manifest(folder)
    if manifest.get("mode") != "rgbd":
        raise ScaleCheckError(
            f"{folder}: a {manifest.get('mode')} session; monocular SLAM has no metric scale, so "
            "the camera's scale is measured on RGB-D sessions"
        )
    applied = manifest.get("config", {}).get("camera", {}).get("scale", {}).get("depth_correction", 1.0)
    try:
        track = read_session_track(folder)
        fit = window_scales(
            track.estimate, tracked_states(track.states), track.ground_truth, association_max_dt_s, settings
        )
    except (LabelError, ScaleCheckError) as e:
        raise ScaleCheckError(f"{folder}: {e}") from None
    return SessionScale(folder, fit, float(applied), str(manifest.get("source", "")))


def sessions_scale_line(folders: list[Path], settings: ScaleSettings, association_max_dt_s: float) -> str:
    """One line on the camera scale of the sessions pooled (what fine-tuning cannot learn), or why it was not
    measured."""
    try:
        fit = ScaleFit.pooled([session_scale(Path(f), settings, association_max_dt_s).fit for f in folders])
    except ScaleCheckError as e:
        return f"camera scale against the ground truth: not measured ({e})"
    warn = (
        "; no model can see a depth scale error: correct it (seesys camera check)"
        if abs(fit.depth_scale_error) > settings.warn_above
        else ""
    )
    return f"camera scale against the ground truth: {describe(fit)}{warn}"
