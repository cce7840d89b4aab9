"""How long a run went without information: the seconds in which the device ran but no fresh input of the
condition's advisory had come (estimates for Equation 2, tracked frames for the motion rules).

Silence in the advisory means "error below α"; a run in which the estimates stopped must say that they did. The
clock starts at the device's first logged frame. Until the first input it allows ``first_estimate_s`` (ORB-SLAM3
initialises and the estimator fills a window), after each input ``stale_after_s`` (the advisory's stale limit);
time beyond that counts as without information, under the reason the app gives for it at that moment. The caller
reports an input with :meth:`InformationClock.estimate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class InformationClock:
    """Seconds without information, in total and per reason; times are the caller's monotonic seconds."""

    stale_after_s: float
    first_estimate_s: float
    seconds_without: float = 0.0
    by_reason: dict[str, float] = field(default_factory=dict)
    _since: float | None = None  # the first frame, then the newest estimate
    _estimated: bool = False
    _checked: float = 0.0  # counted up to here; set with the first frame, read only after it

    def first_frame(self, t: float) -> None:
        if self._since is None:
            self._since = self._checked = t

    def estimate(self, t: float) -> None:
        """A fresh estimate arrived at ``t`` (account the time up to it first with :meth:`advance`)."""
        self._since = self._checked = t
        self._estimated = True

    def _deadline(self) -> float | None:
        """Until when the newest estimate (or the first frame) is fresh enough; None before the first frame."""
        if self._since is None:
            return None
        return self._since + (self.stale_after_s if self._estimated else self.first_estimate_s)

    def lacking(self, t: float) -> bool:
        """True when at ``t`` the device runs and the newest estimate (or the first frame) is too old."""
        deadline = self._deadline()
        return deadline is not None and t > deadline

    def advance(self, t: float, reason: str) -> bool:
        """Count the time up to ``t`` that was without information under ``reason``; returns :meth:`lacking`."""
        deadline = self._deadline()
        if deadline is None or t <= deadline:  # not lacking
            return False
        seconds = t - max(self._checked, deadline)
        self.seconds_without += seconds
        self.by_reason[reason] = self.by_reason.get(reason, 0.0) + seconds
        self._checked = t
        return True
