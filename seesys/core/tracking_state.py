"""ORB-SLAM3's tracking states, with ORB-SLAM3's own numeric values.

Defined here rather than imported from ``pyorbslam3`` so that the estimator and the advisory, which only read
states off the wire and out of logs, do not load the SLAM extension.
"""

from __future__ import annotations

from enum import IntEnum


class TrackingState(IntEnum):
    SYSTEM_NOT_READY = -1
    NO_IMAGES_YET = 0
    NOT_INITIALIZED = 1
    OK = 2
    RECENTLY_LOST = 3
    LOST = 4
    OK_KLT = 5

    @property
    def tracked(self) -> bool:
        """True when the frame has a pose SLAM considers good."""
        return self in (TrackingState.OK, TrackingState.OK_KLT)
