"""The rotation baseline's input: the device's angular speed from the relative rotation in its feature stream.

Each tracked frame's RTS row holds the rotation since the previous tracked frame as rotation-vector components
(``rel_roll``, ``rel_pitch``, ``rel_yaw``, rad/frame; see ``seesys.core.rts_schema``). The study's θ is their RMS,
converted to degrees and divided by the time between the two frames (from the frames' own timestamps, so network
jitter does not enter). Frames SLAM did not track carry no rotation and are skipped; the next tracked frame's
rotation spans the gap, and so does its Δt. A gap longer than ``max_frame_gap_s``, a timestamp that does not
increase, or a non-finite component gives no sample.
"""

from __future__ import annotations

import math

import numpy as np

from seesys.core import rts_schema
from seesys.core.equation2 import RotationConfig
from seesys.core.messages import FeatureFrame

_COLUMNS = [rts_schema.index_of(name) for name in rts_schema.ROTATION_CHANNELS]


class RotationSpeed:
    """Turns consecutive feature frames of one device into angular speeds (°/s)."""

    def __init__(self, cfg: RotationConfig):
        self._max_gap = cfg.max_frame_gap_s
        self._previous: dict[str, float] = {}

    def update(self, frame: FeatureFrame) -> float | None:
        """The speed at this frame, or None when it gives none."""
        if not frame.tracking_state.tracked:
            return None
        rotation = np.asarray(frame.rts, dtype=np.float64)[_COLUMNS]
        previous = self._previous.get(frame.device_id)
        self._previous[frame.device_id] = frame.timestamp
        if previous is None or not np.all(np.isfinite(rotation)):
            return None
        dt = frame.timestamp - previous
        if not 0 < dt <= self._max_gap:
            return None
        rms = math.sqrt(float(np.mean(rotation**2)))
        return math.degrees(rms) / dt
