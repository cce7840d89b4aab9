"""The device settings a model depends on: what a device states in every :class:`~seesys.core.messages.FeatureFrame`
and what a model's compatibility record says it was trained with.

A model reads numbers whose meaning depends on how the device made them: the PSD's cell size and frustum expansion
(its geometry) and the inverse-depth scale of its map-point layer (``near_depth``), the SLAM mode (metric depth in
RGB-D, an arbitrary scale in monocular), the frame rate (a window of T rows is T frames: one second at 30 Hz) and
ORB-SLAM3's feature count (the scale of the match counts), and the camera normalisation version
(:mod:`seesys.core.camera_normalisation`: how pixel-valued channels, image statistics and the PSD grid were made
independent of the camera). A device whose settings differ from the model's gets
estimates that mean nothing, so the service refuses its frames and says which setting differs.

The frame rate is compared in whole frames per second: a source whose nominal rate comes from its timestamps
(29.97 Hz) is a 30 Hz device.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from seesys.core import camera_normalisation

#: The SLAM modes a device may state, in their wire order.
SLAM_MODES = ("rgbd", "mono")
RGBD, MONO = SLAM_MODES


@dataclass(frozen=True)
class DeviceSettings:
    """One device's settings that decide what its features mean (see the module's docstring).

    ``slam_mode``: ``rgbd`` or ``mono``; ``fps``: whole frames per second of the source; ``orb_features``:
    ORB-SLAM3's feature count (``[orb] features`` of slam.toml); ``psd_patch_px``, ``psd_expansion``,
    ``near_depth``: the PSD's cell size (in reference-camera pixels), frustum expansion and map-point depth scale
    (``[psd]`` of monitor.toml); ``camera_normalisation``: the version of the camera normalisation its monitor
    applied.
    """

    slam_mode: str
    fps: int
    orb_features: int
    psd_patch_px: int
    psd_expansion: int
    near_depth: float
    camera_normalisation: int

    def __post_init__(self) -> None:
        if self.slam_mode not in SLAM_MODES:
            raise ValueError(f"slam_mode must be one of {', '.join(SLAM_MODES)}, got {self.slam_mode!r}")

    @classmethod
    def of(
        cls, slam_mode: str, fps: float, orb_features: int, psd_patch_px: int, psd_expansion: int, near_depth: float
    ) -> DeviceSettings:
        """The record of a device running at ``fps`` frames per second (rounded to whole frames) with this
        SEESys's camera normalisation."""
        return cls(
            slam_mode,
            int(round(fps)),
            int(orb_features),
            int(psd_patch_px),
            int(psd_expansion),
            float(near_depth),
            camera_normalisation.VERSION,
        )

    @classmethod
    def from_record(cls, record: dict) -> DeviceSettings:
        """The settings :meth:`as_record` wrote; a record without a camera normalisation version was written
        before camera normalisation existed (version 0)."""
        return cls(**{"camera_normalisation": camera_normalisation.BEFORE_NORMALISATION, **record})

    def as_record(self) -> dict:
        return asdict(self)


def model_settings_record(settings: DeviceSettings, slam_modes: tuple[str, ...] | list[str]) -> dict:
    """What a model's compatibility record holds of the device: ``settings`` with the SLAM modes it was trained
    on in place of one mode."""
    record = settings.as_record()
    del record["slam_mode"]
    return {"slam_modes": sorted(slam_modes), **record}


def settings_differences(model: dict, device: DeviceSettings) -> list[str]:
    """Every setting in which ``device`` differs from a model's record (:func:`model_settings_record`), as
    ``"name: device VALUE, model VALUE"``; empty when the model was made for it."""
    out = []
    if device.slam_mode not in model.get("slam_modes", ()):
        out.append(f"slam_mode: device {device.slam_mode}, model {'/'.join(model.get('slam_modes', ())) or '-'}")
    for name, value in device.as_record().items():
        if name == "slam_mode":
            continue
        expected = model.get(name)
        if expected is None or float(expected) != float(value):
            out.append(f"{name}: device {value:g}, model {'-' if expected is None else format(expected, 'g')}")
    return out
