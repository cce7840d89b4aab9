"""Plan and render one synthetic sequence in the TUM RGB-D layout.

A sequence is fully determined by a :class:`SequenceSpec` (environment preset, motion, seed, length, lens) and
``configs/synth.toml``: every worker process rebuilds the same plan from the spec and renders its share of the
frames, so a re-render is byte-identical whatever the number of processes.

Output folder (read by the ``tum:`` frame source; same convention as the shared synthetic room):
``rgb/<t>.png`` 8-bit gray, ``depth/<t>.png`` 16-bit z-depth × depth_factor, ``rgb.txt``, ``depth.txt``,
``associations.txt``, ``groundtruth.txt`` (T_world_camera, optical frame, world z up), ``calibration.yaml``,
``metadata.json`` (environment, preset, motion group, trajectory, seed, sensor draws) and ``render_log.csv``
(per frame: exposure, light level, signal scale, blur streak).

Rendering and SLAM must never share the CPU (monocular tracking collapses): the dataset builder renders all
sequences first and runs SLAM afterwards.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rich.progress import Progress

from seesys.core.camera import Intrinsics
from seesys.core.errors import SeesysError
from seesys.core.trajectory import tum_line
from synth.camera_effects import LensDistortion, Photometry, image_motion, motion_blur
from synth.config import CameraConfig, CameraModel, EnvironmentPreset, SynthConfig
from synth.environments import Scene, build_scene
from synth.lenses import model_camera, told_lens, true_lens
from synth.real_camera import (
    auto_exposure_response,
    depth_noise,
    jpeg_roundtrip,
    rolling_shutter,
    shift_depth,
)
from synth.renderer import RayGrid, render
from synth.structured_light import as_measured, without_unlit
from synth.trajectories import (
    MOTION_GROUPS,
    SCAN_GROUP,
    Trajectory,
    TrajectoryError,
    generate_motion,
    generate_scan,
    load_euroc,
    load_tum,
    place_real,
)
from synth.wall_objects import place_wall_objects, with_wall_objects

REAL_PREFIX = "real:"


@dataclass(frozen=True)
class SequenceSpec:
    """What to render. ``motion`` is a motion group (patrol, aiming, rapid) or ``real:<name>`` for a real
    trajectory of configs/synth.toml; ``frames`` None renders the configured duration."""

    environment: str
    motion: str
    seed: int
    frames: int | None = None
    width: int | None = None
    height: int | None = None
    blur: bool = True
    distortion: bool = False


@dataclass(frozen=True)
class SequencePlan:
    """Everything a worker needs to render any frame of a sequence."""

    spec: SequenceSpec
    camera: CameraConfig
    scene: Scene
    trajectory: Trajectory
    motion_group: str
    trajectory_name: str
    frame_times: np.ndarray  # seconds from the sequence start
    exposure_s: np.ndarray
    light: np.ndarray
    signal_scale: np.ndarray
    gain: float
    photometry: Photometry
    camera_model: CameraModel
    lens: Intrinsics  # the true lens the frames are seen through (distortion included)
    told: Intrinsics  # the intrinsics calibration.yaml tells SLAM


def _draw_range(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(*bounds))


def plan_sequence(spec: SequenceSpec, config: SynthConfig) -> SequencePlan:
    """Build the scene, the placed trajectory and the per-frame exposure schedule of ``spec``."""
    preset = config.preset(spec.environment)
    model = config.camera_model(preset.camera_model)
    camera = model_camera(config.camera, model)
    native_width = camera.lens.width
    if spec.width or spec.height:
        camera = camera.scaled(spec.width or camera.lens.width, spec.height or camera.lens.height)
    rng = np.random.default_rng([spec.seed, 0x7A7])
    scene = build_scene(preset, spec.seed, config.sensor)
    lo, hi = scene.room_bounds()
    duration = config.trajectory.duration_s if spec.frames is None else spec.frames / camera.fps
    margin = 2 * config.sensor.exposure_max_ms / 1000.0

    if spec.motion.startswith(REAL_PREFIX):
        real = config.real_trajectory(spec.motion[len(REAL_PREFIX) :])
        loader = {"tum": load_tum, "euroc": load_euroc}.get(real.format)
        if loader is None:
            raise TrajectoryError(f"real trajectory {real.name}: unknown format {real.format!r} (tum or euroc)")
        full = loader(config.trajectory_path(real))
        speed = _draw_range(rng, config.trajectory.real_speed_scale)
        length = min((duration + margin) * speed, full.duration)
        start = float(rng.uniform(0.0, full.duration - length))
        recorded = full.window(start, length)
        faster = Trajectory(recorded.times / speed, recorded.positions, recorded.rotations)
        trajectory = place_real(faster, lo, hi, config.trajectory, rng)
        scene = scene.without_boxes_near(trajectory.positions, config.trajectory.box_clearance_m)
        group, name = real.group, real.name
        duration = min(duration, trajectory.duration - margin)
    elif spec.motion == SCAN_GROUP:
        # Boxes against the walls, scanned at close range: clutter is cleared from the path and the boxes' places
        # only (the other motions keep box_clearance_m from every box), then the boxes are added.
        task = config.scan
        objects = place_wall_objects(
            scene.room,
            int(rng.integers(task.objects[0], task.objects[1] + 1)),
            task.object_size_m,
            task.object_height_m,
            task.wall_gap_m,
            rng,
            task.min_spacing_m,
        )
        trajectory = generate_scan(objects, config.motion.scan, task, lo, hi, duration + margin, rng)
        scene = with_wall_objects(scene.without_boxes_near(trajectory.positions, task.path_clearance_m), objects, rng)
        group, name = spec.motion, f"{spec.motion}_{spec.seed}"
    elif spec.motion in MOTION_GROUPS:
        motion = getattr(config.motion, spec.motion)
        trajectory = generate_motion(spec.motion, motion, lo, hi, config.trajectory, duration + margin, rng)
        scene = scene.without_boxes_near(trajectory.positions, config.trajectory.box_clearance_m)
        group, name = spec.motion, f"{spec.motion}_{spec.seed}"
    else:
        raise SeesysError(
            f"unknown motion {spec.motion!r}: use one of {', '.join(MOTION_GROUPS)} or "
            f"{REAL_PREFIX}<name> ({', '.join(r.name for r in config.real_trajectories)})"
        )

    count = int(np.floor(duration * camera.fps)) if spec.frames is None else spec.frames
    if count < 1:
        raise SeesysError(f"sequence too short: {duration:.2f} s gives no frame")
    return plan_frames(spec, config, camera, model, scene, trajectory, group, name, count, rng, native_width)


def plan_frames(
    spec: SequenceSpec,
    config: SynthConfig,
    camera: CameraConfig,
    model: CameraModel,
    scene: Scene,
    trajectory: Trajectory,
    group: str,
    name: str,
    count: int,
    rng: np.random.Generator,
    native_width: int,
) -> SequencePlan:
    """The per-frame exposure, light and noise schedule of ``count`` frames through ``camera`` and ``model``,
    drawn from ``rng`` after the scene and trajectory (the closed-loop study plans its frames the same way, with a
    trajectory that its simulated operator extends as it goes)."""
    margin = 2 * config.sensor.exposure_max_ms / 1000.0
    # The first frame's exposure starts at the trajectory's start.
    frame_times = margin / 2 + np.arange(count) / camera.fps

    sensor = config.sensor
    period = _draw_range(rng, sensor.light_modulation_period_s)
    wave = np.sin(2 * np.pi * frame_times / period + rng.uniform(0, 2 * np.pi))
    wave += 0.5 * np.sin(2 * np.pi * frame_times / (0.37 * period) + rng.uniform(0, 2 * np.pi))
    low, high = sensor.light_modulation
    light = low + (high - low) * (wave - wave.min()) / max(np.ptp(wave), 1e-9) if count > 1 else np.full(1, high)
    base = _draw_range(rng, sensor.base_exposure_ms) / 1000.0
    target = base * light ** (-sensor.auto_exposure_strength)
    if model.auto_exposure_time_constant_s > 0:
        target = np.exp(
            auto_exposure_response(
                np.log(target), camera.fps, model.auto_exposure_time_constant_s, model.auto_exposure_damping
            )
        )
    exposure = np.clip(target, sensor.exposure_min_ms / 1000.0, sensor.exposure_max_ms / 1000.0)
    gain = _draw_range(rng, sensor.gain)
    signal = sensor.signal_scale * gain * light * exposure / base
    noise = model.colour_noise_scale
    photometry = Photometry(
        sensor.signal_scale,
        _draw_range(rng, sensor.shot_noise_dn_per_e) * scene.preset.shot_noise_scale * noise**2,
        _draw_range(rng, sensor.read_noise_dn) * noise,
        sensor.black_level_dn,
    )
    return SequencePlan(
        spec,
        camera,
        scene,
        trajectory,
        group,
        name,
        frame_times,
        exposure,
        light,
        signal,
        gain,
        photometry,
        model,
        true_lens(camera.lens, model, spec.distortion),
        told_lens(camera.lens, model, spec.distortion, native_width),
    )


@dataclass(frozen=True)
class FrameRecord:
    index: int
    exposure_ms: float
    light: float
    signal_scale: float
    blur_p99_px: float
    mean_gray: float


class _Worker:
    """Per-process state: the plan, the ray grid and the lens maps, built once per process."""

    plan: SequencePlan
    grid: RayGrid
    lens: LensDistortion | None
    out: Path
    max_samples: int
    depth_factor: float
    start_time: float

    @classmethod
    def setup(cls, spec: SequenceSpec, config: SynthConfig, out: Path) -> None:
        cv2.setNumThreads(1)  # parallelism is across processes
        cls.plan = plan_sequence(spec, config)
        cls.grid = RayGrid.for_camera(cls.plan.camera)
        distorted = spec.distortion or cls.plan.camera_model.radial_k1 != 0
        cls.lens = LensDistortion.for_lens(cls.plan.lens) if distorted else None
        cls.out = out
        cls.max_samples = config.sensor.blur_max_samples
        cls.depth_factor = config.camera.depth_factor
        cls.start_time = config.start_time_s

    @classmethod
    def render_frame(cls, index: int) -> FrameRecord:
        images = render_images(cls.plan, cls.grid, cls.lens, cls.max_samples, index, cls.plan.trajectory)
        stamp = frame_stamp(cls.start_time + cls.plan.frame_times[index])
        _write_png(cls.out / "rgb" / f"{stamp}.png", images.gray)
        _write_png(cls.out / "depth" / f"{stamp}.png", depth_png(images.depth_m, cls.depth_factor))
        return images.record


@dataclass(frozen=True)
class FrameImages:
    """One frame as the camera delivers it: 8-bit gray, and the z-depth (metres, float32) the sensor reports (its
    scale error included, 0 where it has none), with the frame's render record."""

    gray: np.ndarray
    depth_m: np.ndarray
    record: FrameRecord


def render_images(
    plan: SequencePlan, grid: RayGrid, lens: LensDistortion | None, max_samples: int, index: int, trajectory: Trajectory
) -> FrameImages:
    """Frame ``index`` of ``plan`` seen along ``trajectory``, which must cover the frame's exposure, rolling
    shutter and depth capture (a few milliseconds either side of its time)."""
    model = plan.camera_model
    t = plan.frame_times[index]
    exposure = plan.exposure_s[index]
    readout = model.rolling_shutter_s
    # Poses: mid-exposure, exposure start and end, first and last row read, depth capture.
    times = np.array([t, t - exposure / 2, t + exposure / 2, t - readout / 2, t + readout / 2, t + model.depth_delay_s])
    positions, rotations = trajectory.interpolate(times)
    matrices = rotations.as_matrix()
    sharp = render(plan.scene, matrices[0], positions[0], grid)
    image, streak = sharp.radiance, 0.0

    def flow_to(k: int) -> np.ndarray:
        return image_motion(
            sharp.depth, grid, matrices[k].T @ matrices[0], matrices[k].T @ (positions[0] - positions[k])
        )

    if plan.spec.blur:
        image, streak = motion_blur(image, grid, flow_to(1), flow_to(2), max_samples)
    if readout > 0:
        image = rolling_shutter(image, grid, flow_to(3), flow_to(4))
    view = sharp
    if model.separate_depth_view:
        centre = positions[5] + matrices[5] @ np.asarray(model.depth_offset_m)
        view = render(plan.scene, matrices[5], centre, grid)
    depth = view.depth
    if model.structured_light:  # in the depth camera's own image, before it is registered to colour
        depth = without_unlit(view, grid.lens.fx, model)
    if any(model.depth_misregistration_px):
        depth = shift_depth(depth, model.depth_misregistration_px)
    if lens is not None:
        image, depth = lens.apply(image, depth)
    if model.depth_noise_m_per_m2 > 0:
        depth = depth_noise(depth, model.depth_noise_m_per_m2, np.random.default_rng([plan.spec.seed, index, 0xD3]))
    if model.structured_light:  # the disparity is measured with its noise, then quantised
        depth = as_measured(depth, model)
    rng = np.random.default_rng([plan.spec.seed, index, 0xF1])
    gray = dataclasses.replace(plan.photometry, signal_scale=float(plan.signal_scale[index])).expose(image, rng)
    if model.jpeg_quality > 0:
        gray = jpeg_roundtrip(gray, model.jpeg_quality)
    # The sensor's depth scale error is in what it reports, not in the depth_factor it says it uses.
    reported = depth * np.float32(1 + model.depth_scale_error) if model.depth_scale_error else depth
    record = FrameRecord(
        index, 1000 * exposure, float(plan.light[index]), float(plan.signal_scale[index]), streak, float(gray.mean())
    )
    return FrameImages(gray, reported, record)


def depth_png(depth_m: np.ndarray, depth_factor: float) -> np.ndarray:
    """The 16-bit depth image of a TUM sequence (``depth_factor`` units per metre, 0 = none)."""
    return np.clip(np.rint(depth_m * depth_factor), 0, 65535).astype(np.uint16)


def _write_png(path: Path, image: np.ndarray) -> None:
    # Level 1 of 9: lossless like any level, files ~10 % larger, writes several times faster.
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
        raise SeesysError(f"cannot write {path}")


def frame_stamp(t: float) -> str:
    """The TUM timestamp text of a frame (also its file name)."""
    return f"{t:.6f}"


def render_sequence(
    spec: SequenceSpec,
    config: SynthConfig,
    out: Path,
    processes: int | None = None,
    show_progress: bool = True,
    progress: Progress | None = None,
) -> list[FrameRecord]:
    """Render ``spec`` into the TUM folder ``out`` with ``processes`` worker processes (configured default).

    The frames show on a bar of their own, or, given ``progress``, on a bar of that display, removed at the end."""
    plan = plan_sequence(spec, config)
    (out / "rgb").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    count = len(plan.frame_times)
    workers = processes or config.processes
    records: list[FrameRecord] = []
    own = Progress(disable=not (show_progress and sys.stderr.isatty()), transient=True)
    with own if progress is None else contextlib.nullcontext():
        progress = own if progress is None else progress
        task = progress.add_task(f"render {spec.environment}/{plan.trajectory_name}", total=count)
        if workers <= 1:
            _Worker.setup(spec, config, out)
            for i in range(count):
                records.append(_Worker.render_frame(i))
                progress.advance(task)
        else:
            # Spawned, not forked: a fork after OpenCV has started its thread pool can deadlock the child.
            context = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(
                workers, mp_context=context, initializer=_Worker.setup, initargs=(spec, config, out)
            ) as pool:
                for record in pool.map(_Worker.render_frame, range(count), chunksize=4):
                    records.append(record)
                    progress.advance(task)
        progress.remove_task(task)
    write_sequence_files(plan, config, out, records)
    return records


def preset_record(preset: EnvironmentPreset, model: CameraModel) -> dict:
    """The preset as ``metadata.json`` records it (JSON types), and as a resumed batch compares it.

    The camera model's name is left out when the model is ideal, so the metadata of a render with the ideal camera
    stays as it was before camera models existed; a non-ideal model is recorded in full beside it."""
    record = dataclasses.asdict(preset)
    if model.ideal:
        del record["camera_model"]
    return json.loads(json.dumps(record))


def camera_record(model: CameraModel) -> dict | None:
    """The camera model as ``metadata.json`` records it (JSON types), and as a resumed batch compares it; None for
    an ideal model, which the metadata does not list."""
    return None if model.ideal else json.loads(json.dumps(dataclasses.asdict(model)))


def write_sequence_files(plan: SequencePlan, config: SynthConfig, out: Path, records: list[FrameRecord]) -> None:
    """The TUM list files, ground truth, calibration, metadata and per-frame render log of a rendered plan."""
    stamps = [frame_stamp(config.start_time_s + t) for t in plan.frame_times]
    header = (
        f"# synthetic {plan.scene.preset.name} / {plan.trajectory_name} (seesys synth render, seed {plan.spec.seed})\n"
    )
    with open(out / "rgb.txt", "w") as f:
        f.write("# color images (8-bit grayscale)\n" + header + "# timestamp filename\n")
        f.writelines(f"{s} rgb/{s}.png\n" for s in stamps)
    with open(out / "depth.txt", "w") as f:
        f.write(f"# depth maps (16-bit, metres * {config.camera.depth_factor:g})\n" + header + "# timestamp filename\n")
        f.writelines(f"{s} depth/{s}.png\n" for s in stamps)
    with open(out / "associations.txt", "w") as f:
        f.writelines(f"{s} rgb/{s}.png {s} depth/{s}.png\n" for s in stamps)
    positions, rotations = plan.trajectory.interpolate(plan.frame_times)
    quats = rotations.as_quat()
    with open(out / "groundtruth.txt", "w") as f:
        f.write(
            "# ground truth trajectory T_world_camera (camera = optical frame: x right, y down, z forward)\n"
            "# world: z up, room centre at the origin, floor z=0\n# timestamp tx ty tz qx qy qz qw\n"
        )
        f.writelines(tum_line(s, p, q, decimals=6) for s, p, q in zip(stamps, positions, quats))
    _write_calibration(out / "calibration.yaml", plan, config)
    metadata = {
        "environment": plan.scene.preset.name,
        "preset": preset_record(plan.scene.preset, plan.camera_model),
        "motion_group": plan.motion_group,
        "trajectory": plan.trajectory_name,
        "motion": plan.spec.motion,
        "seed": plan.spec.seed,
        "frames": len(plan.frame_times),
        "fps": plan.camera.fps,
        "blur": plan.spec.blur,
        "distortion": plan.spec.distortion,
        "gain": plan.gain,
        "shot_noise_dn_per_e": plan.photometry.shot_noise_dn_per_e,
        "read_noise_dn": plan.photometry.read_noise_dn,
        "boxes": len(plan.scene.boxes),
        "generator": "seesys synth render (numpy ray caster, procedural textures)",
    }
    if not plan.camera_model.ideal:
        metadata["camera_model"] = camera_record(plan.camera_model)
        metadata["true_lens"] = dataclasses.asdict(plan.lens)  # calibration.yaml has the told one
    with open(out / "metadata.json", "w") as f:
        json.dump(metadata, f, indent=2)
        f.write("\n")
    with open(out / "render_log.csv", "w") as f:
        f.write("timestamp,exposure_ms,light,signal_scale,blur_p99_px,mean_gray\n")
        for s, r in zip(stamps, sorted(records, key=lambda r: r.index)):
            f.write(
                f"{s},{r.exposure_ms:.3f},{r.light:.4f},{r.signal_scale:.4f},{r.blur_p99_px:.2f},{r.mean_gray:.2f}\n"
            )


def _write_calibration(path: Path, plan: SequencePlan, config: SynthConfig) -> None:
    intr = plan.told
    dist = ", ".join(f"{d:g}" for d in intr.distortion)
    text = (
        "# pinhole intrinsics of the synthetic sequence\n"
        "camera_model: pinhole\n"
        f"width: {intr.width}\nheight: {intr.height}\n"
        f"fx: {intr.fx:.6f}\nfy: {intr.fy:.6f}\ncx: {intr.cx:.6f}\ncy: {intr.cy:.6f}\n"
        f"distortion: [{dist}]   # k1 k2 p1 p2 k3\n"
        f"fps: {plan.camera.fps}\n"
        f"depth_factor: {config.camera.depth_factor}   # depth png value / depth_factor = z-depth in metres; 0 "
        f"= invalid\n"
        "image_channels: 1              # rgb/*.png are 8-bit grayscale\n"
        f"generator: seesys synth render, seed {plan.spec.seed}\n"
    )
    path.write_text(text)
