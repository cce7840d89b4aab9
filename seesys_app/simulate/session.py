"""One simulated participant's session, frame by frame in simulated time.

For every frame: the operator moves on to the frame's exposure (hearing only buffers emitted before it), the
renderer draws the frame through the device's camera model, ORB-SLAM3 tracks it, the RTS monitor turns it into a
feature frame, the estimator's window assembler and the shipped model make an estimate at every window end, and the
advisory's pulse rule (Equation 2 or the model's head, the rotation rule, or none) decides the buffers that the
operator hears next. Simulated time is the camera's clock: a frame's timestamp, an estimate's arrival (its frame's
time plus ``estimate_latency_s``) and a buffer's sound (its time plus ``audio_latency_s``) are all on it, and every
log's wall-clock column holds it too.

The attempt folder is written as ``seesys study run`` writes one (docs/study.md): the device session (``frames.csv``,
``trajectory.tum``, ``rts.csv``, ``psd/``, ``session.json``, ``orbslam3.yaml``), ``estimates.csv``, ``advisory.csv``,
``events.csv`` (``initialised`` at the first tracked frame, ``object`` k when the operator finished scanning it),
``run.json``, and the renderer's ground truth as ``groundtruth.tum`` (the motion capture of a real study), so that
``seesys analyze`` reads it unchanged. ``operator.json`` records the simulated participant, ``task.json`` the room.
Every row is flushed as written; told to stop (``stop``, checked before every frame, so that a stop never falls
between a frame's rows and its count) or on Ctrl-C the session ends ``interrupted``, on an error ``failed`` (with
the error in ``run.json`` and ``session.json``), its files final either way.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advisory.advice import Advice, Buffer, RecordedBuffer, ReplayedAdvice
from advisory.conditions import Condition, estimate_reading, feature_reading
from advisory.config import load_advisory_config
from advisory.scheduler import Reading
from estimator.service.device_windows import DeviceWindows
from estimator.service.model import ServedModel
from seesys.core.errors import SeesysError
from seesys.core.messages import Estimate
from seesys.core.session_layout import ADVISORY_COLUMNS, ADVISORY_CSV, GROUND_TRUTH, SETTINGS
from seesys.core.trajectory import Poses
from seesys.io.config import as_dict, replace_fields
from seesys.io.core_settings import load_device_settings, load_label_config
from seesys.io.logfiles import CsvLog, write_json_atomically
from seesys.io.rts_log import RTS_CSV
from seesys.io.session_files import utc_now
from seesys.io.trajectory_files import write_tum
from seesys_app.simulate.config import SimulateConfig
from seesys_app.simulate.operator import Goal, SimulatedOperator, draw_traits
from seesys_app.simulate.oracle import TrueError
from seesys_app.simulate.scan_task import build_scan_task
from slam_monitor.device_worker import corrected_depth
from slam_monitor.frame import Frame
from slam_monitor.monitor import MonitorInput, MonitorStep, PreviousPose
from slam_monitor.monitor_config import load_monitor_config
from slam_monitor.orbslam_settings import SlamMode, build_settings, load_slam_config, vocabulary_path, write_settings
from slam_monitor.session import SessionWriter, prepare_session_folder
from slam_monitor.sources.base import depth_metres
from slam_monitor.sources.settings import load_camera_config
from slam_monitor.tracker import Tracker
from study.estimates import ESTIMATE_COLUMNS, ESTIMATES_CSV
from study.runner import EVENT_COLUMNS
from study.sessions import ADVICE_START, EVENTS_CSV, RUN_JSON
from synth.camera_effects import LensDistortion
from synth.config import load_synth_config
from synth.lenses import model_camera
from synth.renderer import RayGrid
from synth.sequence import SequenceSpec, depth_png, plan_frames, render_images

# The conditions whose advice listens to the estimates (the oracle listens to the truth, the yoked to a recording).
ESTIMATE_CONDITIONS = (Condition.SEESYS, Condition.NONE)
OPERATOR_JSON = "operator.json"
TASK_JSON = "task.json"
DEVICE_ID = "simulated"


@dataclass(frozen=True)
class Participant:
    """A simulated participant: its id, the number its operator is drawn from, and the condition of this session."""

    id: str
    number: int
    condition: str


def true_pose(operator: SimulatedOperator, t: float) -> np.ndarray:
    """The operator's pose at ``t`` (simulated seconds) as position and x y z w quaternion: the ground truth that
    ``groundtruth.tum`` records."""
    positions, rotations = operator.trajectory(since=t).interpolate(np.array([t]))
    return np.concatenate([positions[0], rotations.as_quat()[0]])


@dataclass(frozen=True)
class SessionOutcome:
    folder: Path
    status: str  # completed (every object scanned) or timed_out (max_task_s reached)
    frames: int
    estimates: int
    objects_reached: int


def simulate_session(
    cfg: SimulateConfig,
    participant: Participant,
    folder: Path,
    model_path: Path,
    config_dir: Path | None = None,
    on_frame: Callable[[int, float], None] | None = None,
    stop: Callable[[], bool] | None = None,
    recording: Sequence[RecordedBuffer] | None = None,
) -> SessionOutcome:
    """Run one session into ``folder`` (created; an earlier session's files in it are replaced).

    ``on_frame(frame_index, simulated_time)`` is called after every frame; the session ends ``interrupted`` before
    the first frame at which ``stop()`` is true. ``recording``: the buffers a ``yoked`` session replays
    (``seesys_app.simulate.yoking``). Raises :class:`SeesysError` for a model made for another device (camera,
    resolution, features), settings that cannot work, or a yoked session without a recording."""
    synth = load_synth_config(config_dir)
    task_cfg, ranges, response = cfg.task, cfg.operator, cfg.response
    camera_model = synth.camera_model(task_cfg.camera_model)
    camera = model_camera(synth.camera, camera_model)
    mode = SlamMode(task_cfg.mode)
    task = build_scan_task(
        synth.preset(task_cfg.environment), synth.sensor, task_cfg, ranges.scan_distance_m[1], ranges.scan_arc_deg[1]
    )
    seed = cfg.study.operator_seed * 100_003 + participant.number
    traits = draw_traits(np.random.default_rng([cfg.study.operator_seed, participant.number]), ranges, response)
    goals = [Goal(o.aim, o.viewpoint(traits.scan_distance_m)) for o in task.objects]
    first = task.objects[0]
    start = np.append(goals[0].stand + first.facing * task_cfg.start_offset_m, first.aim[2] + 0.15)
    operator = SimulatedOperator(
        traits,
        goals,
        start,
        task_cfg.settle_s,
        task_cfg.max_task_s,
        getattr(synth.motion, traits.motion_group),
        ranges,
        response,
        seed,
    )
    margin = 2 * synth.sensor.exposure_max_ms / 1000.0
    operator.advance(margin)
    count = int(np.ceil(task_cfg.max_task_s * camera.fps))
    spec = SequenceSpec(task_cfg.environment, "closed-loop", seed)
    plan = plan_frames(
        spec,
        synth,
        camera,
        camera_model,
        task.scene,
        operator.trajectory(),
        traits.motion_group,
        f"scan-{participant.id}",
        count,
        np.random.default_rng([seed, 0x7A7]),
        camera.lens.width,
    )
    grid = RayGrid.for_camera(plan.camera)
    lens = LensDistortion.for_lens(plan.lens) if camera_model.radial_k1 != 0 else None

    slam_config = load_slam_config(config_dir)
    monitor_config = load_monitor_config(config_dir)
    monitor_config = replace_fields(monitor_config, device_id=DEVICE_ID)
    settings = load_device_settings(mode.value, camera.fps, config_dir)
    model = ServedModel.load(model_path, monitor_config.windows)
    refused = model.settings_differences(settings)
    if refused:
        raise SeesysError(f"{model_path} was made for another device: {'; '.join(refused)}")
    advisory_cfg = load_advisory_config(config_dir)
    depth_correction = load_camera_config(config_dir).scale.depth_correction
    intrinsics = plan.told
    condition = Condition(participant.condition)
    if condition is Condition.YOKED and recording is None:
        raise SeesysError("a yoked session needs the pulses of its partner's seesys session to replay")

    # The advisory's clock starts at the first frame (a yoked session replays from there too).
    advice_start = float(synth.start_time_s + plan.frame_times[0])
    folder = prepare_session_folder(folder)
    for name in (ESTIMATES_CSV, ADVISORY_CSV, EVENTS_CSV, RTS_CSV):
        (folder / name).unlink(missing_ok=True)
    write_json_atomically(
        folder / OPERATOR_JSON,
        {"participant": participant.id, "number": participant.number, "seed": seed, **traits.record()},
    )
    write_json_atomically(
        folder / TASK_JSON,
        {
            "environment": task_cfg.environment,
            "layout_seed": task_cfg.layout_seed,
            "camera_model": task_cfg.camera_model,
            "objects": [o.record() for o in task.objects],
        },
    )
    write_json_atomically(
        folder / RUN_JSON,
        {
            "participant": participant.id,
            "phase": "task",
            "condition": condition.value,
            "status": "running",
            "simulated": True,
            "pid": os.getpid(),
            "started": utc_now(),
            "model_version": model.version,
            "source": f"simulated:{task_cfg.environment}/{task_cfg.camera_model}",
            ADVICE_START: advice_start,
        },
    )
    writer = SessionWriter(
        folder,
        {
            "source": f"simulated:{task_cfg.environment}",
            "mode": mode.value,
            "max_frames": count,
            "vocabulary": str(vocabulary_path(slam_config)),
            "settings_file": SETTINGS,
            "config": {"slam": as_dict(slam_config)},
        },
    )
    writer.describe_source(
        f"simulated operator {participant.id} in {task_cfg.environment} ({task_cfg.camera_model} camera)",
        as_dict(intrinsics),
        camera.fps,
    )
    events = CsvLog(folder / EVENTS_CSV, EVENT_COLUMNS)
    estimates_log = CsvLog(folder / ESTIMATES_CSV, ESTIMATE_COLUMNS)
    monitor = MonitorStep(monitor_config, folder, settings=settings)
    start_time = synth.start_time_s
    advice: Advice | ReplayedAdvice = (
        ReplayedAdvice(recording or (), advisory_cfg, advice_start, cfg.loop.audio_latency_s)
        if condition is Condition.YOKED
        else Advice(condition, advisory_cfg, advice_start, cfg.loop.audio_latency_s)
    )
    advisory_log = CsvLog(folder / ADVISORY_CSV, ADVISORY_COLUMNS)

    def play(buffers: list[Buffer]) -> None:
        for buffer in buffers:
            advisory_log.write(*buffer.row(buffer.decision.time, condition))
            operator.hear(buffer.play_at - start_time, buffer.heard_pulses)

    reading = estimate_reading(advisory_cfg)
    features_reading = feature_reading(condition, advisory_cfg) if condition.hears_features else None
    true_error_of = TrueError(mode is SlamMode.MONO, load_label_config(config_dir).delta_frames)
    windows = DeviceWindows(model, monitor_config.windows)
    version = model.version
    events.write(start_time, "start", f"simulated {condition.value}")

    settings_file = write_settings(folder / SETTINGS, build_settings(intrinsics, camera.fps, mode, slam_config))
    tracker = Tracker(vocabulary_path(slam_config), settings_file, mode, intrinsics)
    status, frames, estimates, initialised, reported = "interrupted", 0, 0, False, 0
    error: str | None = None
    previous = PreviousPose()
    stopped = False
    try:
        for k in range(count):
            if stop is not None and stop():
                stopped = True
                break
            t = float(plan.frame_times[k])
            stamp = start_time + t
            operator.advance(t + margin)
            images = render_images(
                plan, grid, lens, synth.sensor.blur_max_samples, k, operator.trajectory(since=t - margin)
            )
            depth = None
            if mode is SlamMode.RGBD:
                # as the device reads the sequence's depth PNG, with the camera's correction
                depth = corrected_depth(
                    depth_metres(depth_png(images.depth_m, synth.camera.depth_factor), synth.camera.depth_factor),
                    depth_correction,
                )
            frame = Frame(k, stamp, images.gray, intrinsics, depth)
            output = tracker.track(frame)
            writer.write_frame(output)
            frames += 1
            if output.tracked and not initialised:
                events.write(stamp, "initialised", "first tracked frame")
                initialised = True
            features = monitor.step(MonitorInput.of(frame, output, previous))
            arrival = stamp + cfg.loop.estimate_latency_s
            if features_reading is not None:
                sample = features_reading(features)
                if sample is not None:
                    play(advice.take(arrival, sample))
            true_error = (
                true_error_of.update(stamp, output.pose_wc if output.tracked else None, true_pose(operator, t))
                if condition is Condition.ORACLE
                else None
            )
            window = windows.add(features).window
            if window is not None:
                batch = model.estimate_batch([window])
                estimate = Estimate(DEVICE_ID, k, stamp, float(batch.errors_m[0]), version, head=batch.head(0))
                estimates_log.write(arrival, DEVICE_ID, k, stamp, estimate.error_m, version)
                estimates += 1
                sample = reading(estimate)
                if condition in ESTIMATE_CONDITIONS and sample is not None:
                    play(advice.take(arrival, sample))
            if window is not None and true_error is not None:
                # at the estimator's cadence and latency: the same windows, the truth in place of the estimate
                play(advice.take(arrival, Reading(true_error)))
            play(advice.until(stamp))
            for number, at in operator.reached[reported:]:
                events.write(start_time + at, "object", str(number))
            reported = len(operator.reached)
            if on_frame is not None:
                on_frame(k, t)
            if operator.done:
                break
        status = "interrupted" if stopped else "completed" if operator.done else "timed_out"
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # recorded as the device and the study record a failure, then passed on
        status, error = "failed", str(e) if isinstance(e, SeesysError) else f"{type(e).__name__}: {e}"
        raise
    finally:
        tracker.shutdown()
        monitor.close_logs()
        last_time = max([float(plan.frame_times[max(frames - 1, 0)])] + [at for _, at in operator.reached])
        events.write(start_time + last_time, "stop", status)
        for csv_log in (events, estimates_log, advisory_log):
            csv_log.close()
        truth = operator.trajectory()
        times = plan.frame_times[:frames]
        positions, rotations = truth.interpolate(times)
        write_tum(folder / GROUND_TRUTH, Poses(start_time + times, positions, rotations.as_quat()))
        ended = status if status in ("interrupted", "failed") else "completed"
        writer.finish(ended, **({"error": error} if error else {}))
        run = json.loads((folder / RUN_JSON).read_text())
        run.update(
            status=ended,
            error=error,
            ended=utc_now(),
            outcome=status,
            frames=frames,
            estimates=estimates,
            buffers=advice.buffers,
            objects_reached=len(operator.reached),
            warnings_heeded=operator.warnings_heeded,
            calibration="the source's ground truth kept",
        )
        write_json_atomically(folder / RUN_JSON, run)
    return SessionOutcome(folder, status, frames, estimates, len(operator.reached))
