"""The typed form of ``configs/synth.toml``: camera, sensor model, trajectory placement, motion groups and the
environment presets."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from seesys.core.camera import Intrinsics
from seesys.core.errors import ConfigError
from seesys.io import resources
from seesys.io.config import load_section


@dataclass(frozen=True)
class CameraConfig:
    """The rendered camera. Frames are ray-cast through the ideal pinhole of ``lens``; its distortion is applied
    only when a render asks for it."""

    lens: Intrinsics
    fps: float
    depth_factor: float
    near_m: float

    def scaled(self, width: int, height: int) -> CameraConfig:
        """The same lens on a sensor of ``width``×``height``."""
        return dataclasses.replace(self, lens=self.lens.scaled(width, height))


@dataclass(frozen=True)
class SensorConfig:
    base_exposure_ms: tuple[float, float]
    exposure_min_ms: float
    exposure_max_ms: float
    light_modulation: tuple[float, float]
    light_modulation_period_s: tuple[float, float]
    auto_exposure_strength: float
    signal_scale: float
    gain: tuple[float, float]
    shot_noise_dn_per_e: tuple[float, float]
    read_noise_dn: tuple[float, float]
    black_level_dn: float
    blur_max_samples: int
    texture_levels: int
    texture_size: int


@dataclass(frozen=True)
class TrajectoryConfig:
    duration_s: float
    wall_margin_m: float
    box_clearance_m: float
    real_fill: float
    real_speed_scale: tuple[float, float]
    camera_height_m: tuple[float, float]


@dataclass(frozen=True)
class MotionGroupConfig:
    """Parameters of one generated motion group (paper Table 2); ranges are drawn per sequence."""

    walk_speed_mps: tuple[float, float]
    yaw_rate_dps: tuple[float, float]
    speed_scale: tuple[float, float]
    shake_deg: float
    shake_m: float
    shake_hz: tuple[float, float]
    wave_deg: float
    wave_hz: tuple[float, float]
    jerk_rate_hz: float
    jerk_deg: float


@dataclass(frozen=True)
class MotionConfig:
    patrol: MotionGroupConfig
    aiming: MotionGroupConfig
    rapid: MotionGroupConfig
    scan: MotionGroupConfig


@dataclass(frozen=True)
class ScanConfig:
    """The ``scan`` group's task (``[scan]``): boxes against the walls, each walked to and swept round at close
    range; ranges are drawn per sequence."""

    objects: tuple[int, int]
    object_size_m: tuple[float, float]
    object_height_m: tuple[float, float]
    wall_gap_m: float
    distance_m: tuple[float, float]
    arc_deg: tuple[float, float]
    sweep_dps: tuple[float, float]
    look_around_deg: tuple[float, float]
    walk_accel_mps2: float
    path_clearance_m: float
    back_off_m: float
    min_spacing_m: float

    def __post_init__(self) -> None:
        if self.objects[0] < 2 or self.objects[1] < self.objects[0]:
            raise ConfigError(f"synth.toml [scan]: objects must be a range from 2 up, got {list(self.objects)}")


@dataclass(frozen=True)
class CameraModel:
    """What a real RGB-D camera adds to the ideal rendered one (synth/real_camera.py,
    synth/structured_light.py, synth/lenses.py); every effect is off at zero
    (``auto_exposure_damping`` and ``colour_noise_scale`` at 1). A value out of its range raises a
    :class:`ConfigError` naming the model and the key."""

    name: str
    depth_offset_m: tuple[float, float, float]
    depth_misregistration_px: tuple[float, float]
    depth_delay_s: float
    rolling_shutter_s: float
    auto_exposure_time_constant_s: float
    auto_exposure_damping: float
    depth_noise_m_per_m2: float
    colour_noise_scale: float
    depth_scale_error: float
    told_focal_error: float
    told_principal_point_px: tuple[float, float]
    radial_k1: float
    projector_offset_m: float
    disparity_step_px: float
    disparity_focal_px: float
    dark_albedo: float
    depth_min_m: float
    depth_max_m: float
    jpeg_quality: int
    resolution_px: tuple[int, int]
    horizontal_fov_deg: float

    def __post_init__(self) -> None:
        where = f"synth.toml: camera model {self.name!r}"
        for key, (low, high) in _MODEL_RANGES.items():
            value = getattr(self, key)
            for v in value if isinstance(value, tuple) else (value,):
                if not low <= v <= high:
                    raise ConfigError(f"{where}: {key} must be within [{low:g}, {high:g}], got {value!r}")
        if self.disparity_step_px > 0 and (self.projector_offset_m == 0 or self.disparity_focal_px == 0):
            raise ConfigError(
                f"{where}: disparity_step_px needs the baseline projector_offset_m and the focal "
                f"length disparity_focal_px (both non-zero)"
            )
        if any(self.resolution_px) and min(self.resolution_px) < 16:
            raise ConfigError(
                f"{where}: resolution_px must be [0, 0] (the [camera.lens] sensor) or at least "
                f"16 px a side, got {list(self.resolution_px)}"
            )
        if 0 < self.depth_max_m <= self.depth_min_m:
            raise ConfigError(f"{where}: depth_max_m {self.depth_max_m:g} must exceed depth_min_m {self.depth_min_m:g}")

    @property
    def separate_depth_view(self) -> bool:
        """True when depth is seen from another pose than colour (offset or delayed) and must be ray-cast apart."""
        return any(self.depth_offset_m) or self.depth_delay_s != 0

    @property
    def structured_light(self) -> bool:
        """True when the depth has any fault of a structured-light sensor (synth/structured_light.py)."""
        return (
            self.projector_offset_m != 0
            or self.disparity_step_px != 0
            or self.dark_albedo != 0
            or self.depth_min_m != 0
            or self.depth_max_m != 0
        )

    @property
    def own_sensor(self) -> bool:
        """True when the model has its own resolution or field of view instead of the [camera.lens] ones."""
        return any(self.resolution_px) or self.horizontal_fov_deg != 0

    @property
    def told_differs(self) -> bool:
        """True when the intrinsics told to SLAM are not the rendered lens's."""
        return self.told_focal_error != 0 or any(self.told_principal_point_px) or self.radial_k1 != 0

    @property
    def ideal(self) -> bool:
        """True when the model changes nothing: the renders are the ideal camera's, byte for byte."""
        return (
            not self.separate_depth_view
            and not any(self.depth_misregistration_px)
            and self.rolling_shutter_s == 0
            and self.auto_exposure_time_constant_s == 0
            and self.depth_noise_m_per_m2 == 0
            and self.colour_noise_scale == 1
            and self.depth_scale_error == 0
            and not self.told_differs
            and not self.structured_light
            and self.jpeg_quality == 0
            and not self.own_sensor
        )


# The values a camera model may take (inclusive): wide enough for any real camera, narrow enough to catch a typo
# (a per-cent value written as 5 instead of 0.05, a damping of 0 that never settles).
_MODEL_RANGES: dict[str, tuple[float, float]] = {
    "depth_offset_m": (-0.5, 0.5),
    "depth_misregistration_px": (-50.0, 50.0),
    "depth_delay_s": (-0.1, 0.1),
    "rolling_shutter_s": (0.0, 0.1),
    "auto_exposure_time_constant_s": (0.0, 5.0),
    "auto_exposure_damping": (0.05, 5.0),
    "depth_noise_m_per_m2": (0.0, 0.1),
    "colour_noise_scale": (0.0, 10.0),
    "depth_scale_error": (-0.3, 0.3),
    "told_focal_error": (-0.3, 0.3),
    "told_principal_point_px": (-100.0, 100.0),
    "radial_k1": (-0.5, 0.5),
    "projector_offset_m": (-0.5, 0.5),
    "disparity_step_px": (0.0, 1.0),
    "disparity_focal_px": (0.0, 5000.0),
    "dark_albedo": (0.0, 1.0),
    "depth_min_m": (0.0, 10.0),
    "depth_max_m": (0.0, 100.0),
    "jpeg_quality": (0, 100),
    "resolution_px": (0, 8192),
    "horizontal_fov_deg": (0.0, 170.0),
}


@dataclass(frozen=True)
class EnvironmentPreset:
    """How one kind of environment looks: size, clutter, texture statistics and lighting."""

    name: str
    room_m: tuple[float, float, float]
    boxes: int
    box_m: tuple[float, float]
    texture_density: float
    texture_contrast: float
    texture_scale_m: float
    poor_walls: int
    bare_floor_ceiling: bool
    poor_boxes: float
    bare_fixture_density: float
    light: float
    falloff_m: float
    ambient: float
    albedo: float
    albedo_spread: float
    shot_noise_scale: float
    camera_model: str


@dataclass(frozen=True)
class RealTrajectory:
    """A real trajectory file under ``trajectory_dir``, and the Table 2 motion group it counts in."""

    name: str
    file: str
    format: str
    group: str


@dataclass(frozen=True)
class SynthConfig:
    processes: int
    start_time_s: float
    trajectory_dir: str
    camera: CameraConfig
    sensor: SensorConfig
    trajectory: TrajectoryConfig
    motion: MotionConfig
    scan: ScanConfig
    real_trajectories: list[RealTrajectory]
    camera_models: list[CameraModel]
    presets: list[EnvironmentPreset]

    def preset(self, name: str) -> EnvironmentPreset:
        """The preset called ``name``; a :class:`ConfigError` lists the known ones otherwise."""
        for preset in self.presets:
            if preset.name == name:
                return preset
        known = ", ".join(p.name for p in self.presets)
        raise ConfigError(f"unknown environment preset {name!r} (configs/synth.toml has: {known})")

    def camera_model(self, name: str) -> CameraModel:
        """The camera model called ``name``; a :class:`ConfigError` lists the known ones otherwise."""
        for model in self.camera_models:
            if model.name == name:
                return model
        known = ", ".join(m.name for m in self.camera_models)
        raise ConfigError(f"unknown camera model {name!r} (configs/synth.toml has: {known})")

    def seen_through(self, environment: str, model: CameraModel) -> SynthConfig:
        """This config with the preset ``environment`` rendered through ``model`` (added to the camera models, or
        replacing the one of its name)."""
        self.preset(environment)  # refuse an unknown preset by name
        models = [m for m in self.camera_models if m.name != model.name] + [model]
        presets = [
            dataclasses.replace(p, camera_model=model.name) if p.name == environment else p for p in self.presets
        ]
        return dataclasses.replace(self, camera_models=models, presets=presets)

    def real_trajectory(self, name: str) -> RealTrajectory:
        for real in self.real_trajectories:
            if real.name == name:
                return real
        known = ", ".join(r.name for r in self.real_trajectories)
        raise ConfigError(f"unknown real trajectory {name!r} (configs/synth.toml has: {known})")

    def trajectory_path(self, real: RealTrajectory) -> Path:
        """Where the file of ``real`` is: ``trajectory_dir`` is relative to the project root."""
        return resources.resolve(self.trajectory_dir) / real.file


def load_synth_config(directory: Path | None = None) -> SynthConfig:
    """Load ``configs/synth.toml``."""
    return load_section("synth", SynthConfig, directory)
