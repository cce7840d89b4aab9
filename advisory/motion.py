"""The ``motion`` condition's input: the motion statistic (``seesys.core.motion``) of the device's feature stream.

Each tracked frame's RTS row holds the translation since the previous tracked frame (``rel_tx``, ``rel_ty``,
``rel_tz``, metres; ``seesys.core.rts_schema``); divided by the time between the two frames it is the frame's
velocity. The statistic at a frame is the spread of the velocities of the tracked frames of the last
``statistic_window_s`` (at least three), in m/s. As for the rotation speed, frames SLAM did not track are skipped,
and a gap longer than ``motion_max_frame_gap_s``, a timestamp that does not increase or a non-finite component
starts the window afresh.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from advisory.config import MotionConfig
from seesys.core import rts_schema
from seesys.core.messages import FeatureFrame
from seesys.core.motion import translation_spread

_COLUMNS = [rts_schema.index_of(name) for name in rts_schema.TRANSLATION_CHANNELS]
# The fewest velocities a spread is taken of.
_MIN_FRAMES = 3


class MotionStatistic:
    """Turns consecutive feature frames of one device into the motion statistic (m/s)."""

    def __init__(self, cfg: MotionConfig):
        self._window_s = cfg.statistic_window_s
        self._max_gap = cfg.motion_max_frame_gap_s
        self._previous: dict[str, float] = {}
        self._recent: dict[str, deque[tuple[float, np.ndarray]]] = {}

    def update(self, frame: FeatureFrame) -> float | None:
        """The statistic at this frame, or None when it gives none."""
        if not frame.tracking_state.tracked:
            return None
        device, t = frame.device_id, frame.timestamp
        displacement = np.asarray(frame.rts, dtype=np.float64)[_COLUMNS]
        previous = self._previous.get(device)
        self._previous[device] = t
        recent = self._recent.setdefault(device, deque())
        if previous is None or not np.all(np.isfinite(displacement)) or not 0 < t - previous <= self._max_gap:
            recent.clear()
            return None
        recent.append((t, displacement / (t - previous)))
        while recent[0][0] <= t - self._window_s:
            recent.popleft()
        if len(recent) < _MIN_FRAMES:
            return None
        return float(translation_spread(np.array([v for _, v in recent])))
