"""The record every frame source yields, and the camera intrinsics that travel with it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seesys.core.camera import Intrinsics


@dataclass(frozen=True)
class Frame:
    """One camera frame as SLAM consumes it.

    ``index`` counts frames from 0 in the order the source delivered them; ``timestamp`` is in seconds on the
    source's clock; ``gray`` is (H, W) uint8; ``depth``, when the source has it, is (H, W) float32 metres aligned
    to ``gray``, 0 where unknown.
    """

    index: int
    timestamp: float
    gray: np.ndarray
    intrinsics: Intrinsics
    depth: np.ndarray | None = field(default=None)
