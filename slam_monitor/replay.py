"""Recorded monitor inputs: what ORB-SLAM3 handed the monitor for each frame of a source, kept in memory so that
the monitor's channels can be replayed and timed offline (the per-channel benchmark, the tests that hold each
channel to its reference computation)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from slam_monitor.device_worker import SessionOptions, run_device_session
from slam_monitor.frame import Frame
from slam_monitor.monitor import MonitorInput, PreviousPose
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.tracker import TrackOutput


class InputRecorder:
    """A device-worker observer that keeps every frame's :class:`MonitorInput`, in order (frames and images are
    kept by reference: a 640×480 RGB-D frame holds about 1.5 MB)."""

    def __init__(self) -> None:
        self.inputs: list[MonitorInput] = []
        self._previous = PreviousPose()

    def on_frame(self, frame: Frame, result: TrackOutput) -> None:
        self.inputs.append(MonitorInput.of(frame, result, self._previous))

    def close(self) -> None:
        """Nothing to release: the inputs stay for the caller."""


def record_inputs(source: str, mode: SlamMode, max_frames: int | None = None) -> list[MonitorInput]:
    """Track ``source`` (``KIND:PATH``) with ORB-SLAM3 in this process, unpaced, and return each frame's monitor
    input. The session folder is temporary. Raises :class:`seesys.core.errors.SeesysError` as a device session
    does (a bad source, a failed tracker)."""
    recorder = InputRecorder()
    with tempfile.TemporaryDirectory() as tmp:
        run_device_session(
            SessionOptions(source=source, mode=mode, out_dir=Path(tmp) / "session", max_frames=max_frames, pace=False),
            observers=[recorder],
        )
    return recorder.inputs
