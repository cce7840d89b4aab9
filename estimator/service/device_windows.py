"""The estimator's window step of the per-frame chain: feature frames of any number of devices → windows the model
takes.

Per device a :class:`~seesys.core.windows.WindowAssembler`, started afresh when the device restarts (a new stream
session, or frame indices that do not increase: rows of its last session must not fill the new session's windows);
frames ending a window whose device settings differ from the model's (or state none; the stream states them on those
frames, with the PSD) and windows of another PSD shape are refused with the reason the service counts; for a model
that reads no PSD the windows are formed without PSDs (:class:`~seesys.core.windows.WindowAssembler` with ``psd``
False). The service
worker adds every frame it receives; the simulated study adds its device's frames in its loop; both then run the model
on the windows this gives.
"""

from __future__ import annotations

from dataclasses import dataclass

from estimator.service.model import ServedModel
from seesys.core.messages import FeatureFrame
from seesys.core.windows import WindowAssembler, WindowConfig, WindowSample

SETTINGS_MISMATCH = "settings_mismatch"
SHAPE_MISMATCH = "shape_mismatch"


@dataclass(frozen=True)
class Added:
    """What one frame gave: a window the model takes (``window``), or the reason a frame or window was refused
    (``refused``: settings_mismatch, shape_mismatch, or the assembler's missing_rts / missing_psd), or neither (no
    window ends here); ``restarted``: the frame started its device afresh; ``formed``: a window ended here, taken or
    refused for its shape."""

    window: WindowSample | None = None
    refused: str | None = None
    restarted: bool = False
    formed: bool = False


class DeviceWindows:
    """The windows of every device whose frames are added, for one model."""

    def __init__(self, model: ServedModel, windows: WindowConfig):
        self._model = model
        self._windows = windows
        self._assemblers: dict[str, WindowAssembler] = {}
        self._last_index: dict[str, int] = {}
        self._session: dict[str, int] = {}
        self._checked: dict[str, tuple[int, object, list[str]]] = {}  # device → (session, settings, differences)

    def settings_differences(self, frame: FeatureFrame) -> tuple[list[str], bool]:
        """How the frame's device settings differ from the model's (empty: served), and whether that is news for
        its stream session (so that a caller logs a refusal once)."""
        checked = self._checked.get(frame.device_id)
        if checked is not None and checked[:2] == (frame.stream_session, frame.settings):
            return checked[2], False
        differences = self._model.settings_differences(frame.settings)
        self._checked[frame.device_id] = (frame.stream_session, frame.settings, differences)
        return differences, True

    def add(self, frame: FeatureFrame) -> Added:
        """Add one frame of its device (see the module docstring)."""
        if frame.states_settings:
            differences, _ = self.settings_differences(frame)
            if differences:
                return Added(refused=SETTINGS_MISMATCH)
        device = frame.device_id
        restarted = frame.stream_session != self._session.get(
            device, frame.stream_session
        ) or frame.frame_index <= self._last_index.get(device, -1)
        if restarted:
            self._assemblers.pop(device, None)
        self._session[device] = frame.stream_session
        self._last_index[device] = frame.frame_index
        assembler = self._assemblers.get(device)
        if assembler is None:
            assembler = self._assemblers[device] = WindowAssembler(self._windows, psd=self._model.reads_psd)
        sample = assembler.add(frame)
        if sample is None:
            return Added(refused=assembler.refused, restarted=restarted)
        if not self._model.accepts(sample):
            return Added(refused=SHAPE_MISMATCH, restarted=restarted, formed=True)
        return Added(window=sample, restarted=restarted, formed=True)
