"""Camera trajectories for rendering: real handheld/MAV ground truth placed into a room, and generated handheld
motion in the three motion groups of the paper's Table 2.

A :class:`Trajectory` holds T_world_camera (optical frame: x right, y down, z forward) at increasing
timestamps and interpolates it (linear position, slerp rotation), so that a renderer can ask for the pose at any
sub-frame time of an exposure. It is made from :class:`seesys.core.trajectory.Poses`, the pose container of files and
logs, and adds what only rendering needs: continuous time.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from seesys.core.trajectory import Poses, TrajectoryError
from seesys.io.trajectory_files import read_euroc_groundtruth, read_tum
from synth.config import MotionGroupConfig, ScanConfig, TrajectoryConfig
from synth.wall_objects import WallObject

#: The paper's Table 2 groups, generated inside a room.
TABLE2_GROUPS = ("patrol", "aiming", "rapid")
#: Scanning boxes against the walls at close range (:func:`generate_scan`), as the simulated study's task does.
SCAN_GROUP = "scan"
MOTION_GROUPS = (*TABLE2_GROUPS, SCAN_GROUP)
# Sampling rate of generated motion before it is interpolated to frame and exposure times.
GENERATED_RATE_HZ = 240.0


@dataclass(frozen=True)
class Trajectory:
    times: np.ndarray  # (N,) seconds, increasing
    positions: np.ndarray  # (N, 3) camera centres in the world
    rotations: Rotation  # N rotations R_world_camera

    def __post_init__(self) -> None:
        if len(self.times) < 2 or np.any(np.diff(self.times) <= 0):
            raise TrajectoryError("a trajectory needs at least 2 poses with strictly increasing timestamps")

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    def interpolate(self, times: np.ndarray) -> tuple[np.ndarray, Rotation]:
        """Positions (M×3) and rotations at ``times`` (clamped to the trajectory's time span)."""
        t = np.clip(times, self.times[0], self.times[-1])
        positions = np.column_stack([np.interp(t, self.times, self.positions[:, k]) for k in range(3)])
        return positions, Slerp(self.times, self.rotations)(t)

    def window(self, start: float, duration: float) -> Trajectory:
        """The part from ``start`` (relative to the first pose) lasting ``duration``, re-timed to start at 0."""
        t0 = self.times[0] + start
        keep = (self.times >= t0) & (self.times <= t0 + duration)
        return Trajectory(self.times[keep] - t0, self.positions[keep], self.rotations[np.flatnonzero(keep)])

    def clipped(self, lo: np.ndarray, hi: np.ndarray) -> Trajectory:
        """The same path with its positions clipped into the box ``lo``..``hi``."""
        return Trajectory(self.times, np.clip(self.positions, lo, hi), self.rotations)


def from_poses(poses: Poses) -> Trajectory:
    """The renderable path through ``poses`` (time-ordered; of poses with equal timestamps the first is kept)."""
    poses = poses.sorted_unique()
    return Trajectory(poses.timestamps, poses.positions, poses.rotations)


def load_tum(path: Path) -> Trajectory:
    """A TUM trajectory file (:func:`seesys.core.trajectory.read_tum`)."""
    return from_poses(read_tum(path))


def load_euroc(path: Path) -> Trajectory:
    """A EuRoC ground-truth CSV (:func:`seesys.core.trajectory.read_euroc_groundtruth`)."""
    return from_poses(read_euroc_groundtruth(path))


def look_rotation(forward: np.ndarray) -> Rotation:
    """R_world_camera for an optical camera looking along ``forward`` (N×3) with the world z axis up."""
    f = forward / np.linalg.norm(forward, axis=1, keepdims=True)
    right = np.cross(f, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(f, right)
    return Rotation.from_matrix(np.stack([right, down, f], axis=2))


def place_real(
    trajectory: Trajectory, room_lo: np.ndarray, room_hi: np.ndarray, config: TrajectoryConfig, rng: np.random.Generator
) -> Trajectory:
    """Place a real trajectory in a room: turn it about the vertical to face a random heading, scale it down to
    fit and move it inside the room, clear of the walls.

    The source world frames are gravity-aligned with z up (TUM motion capture, EuRoC Vicon), so the camera's
    tilt is kept and only the heading of its mean viewing direction changes; positions are scaled by
    ``min(1, fill·room / extent)`` so that a large (MAV, walking) trajectory fits a small room; the camera's mean
    height is set inside the configured range.
    """
    view = trajectory.rotations.as_matrix()[:, :, 2].mean(axis=0)
    heading = rng.uniform(-np.pi, np.pi)
    place = Rotation.from_euler("z", heading - np.arctan2(view[1], view[0]))
    centred = place.apply(trajectory.positions - trajectory.positions.mean(axis=0))

    inner_lo, inner_hi = room_lo + config.wall_margin_m, room_hi - config.wall_margin_m
    extent = np.maximum(centred.max(axis=0) - centred.min(axis=0), 1e-6)
    room_span = inner_hi - inner_lo
    scale = min(1.0, *(config.real_fill * room_span[:2] / extent[:2]), 0.9 * room_span[2] / extent[2])
    scaled = centred * scale
    lo, hi = scaled.min(axis=0), scaled.max(axis=0)
    # Anywhere the whole path fits horizontally; the height so that the mean lies in the configured range.
    offset = np.array(
        [rng.uniform(inner_lo[k] - lo[k], max(inner_hi[k] - hi[k], inner_lo[k] - lo[k])) for k in range(2)]
        + [rng.uniform(*config.camera_height_m)]
    )
    positions = np.clip(scaled + offset, inner_lo, inner_hi)
    return Trajectory(trajectory.times - trajectory.times[0], positions, place * trajectory.rotations)


def smooth_noise(
    rng: np.random.Generator,
    t: np.ndarray,
    band_hz: tuple[float, float],
    components: int = 4,
) -> np.ndarray:
    """Band-limited noise with unit RMS: a sum of sinusoids at random frequencies in ``band_hz``."""
    freqs = rng.uniform(*band_hz, components)
    phases = rng.uniform(0, 2 * np.pi, components)
    return np.sqrt(2.0 / components) * np.sin(2 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0)


def jerk_offsets(rng: np.random.Generator, t: np.ndarray, rate_hz: float, amplitude: float) -> np.ndarray:
    """Sudden out-and-back turns of the hand (yaw, pitch offsets, 2×N): Poisson events at ``rate_hz``, each a
    sin² bump of 0.5-1 × ``amplitude`` lasting 0.15-0.35 s (peak rates of 100-300 deg/s for 15°). They are
    rare and short, and with the exposure they make the motion-blur bursts of real handheld footage."""
    out = np.zeros((2, len(t)))
    for _ in range(rng.poisson(rate_hz * (t[-1] - t[0]))):
        start, length = rng.uniform(t[0], t[-1]), rng.uniform(0.15, 0.35)
        size = amplitude * rng.uniform(0.5, 1.0) * rng.choice([-1.0, 1.0])
        inside = (t >= start) & (t <= start + length)
        out[0 if rng.uniform() < 0.7 else 1, inside] += size * np.sin(np.pi * (t[inside] - start) / length) ** 2
    return out


def min_jerk(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x**2)


def generate_motion(
    group: str,
    motion: MotionGroupConfig,
    room_lo: np.ndarray,
    room_hi: np.ndarray,
    config: TrajectoryConfig,
    duration: float,
    rng: np.random.Generator,
) -> Trajectory:
    """Generated handheld motion of one Table 2 group inside a room.

    - ``patrol``: walking round the room on a wobbly loop, looking ahead and out towards the walls, with gait bob.
    - ``aiming``: standing at a few spots, aiming at points on the walls with smooth (minimum-jerk) re-aims and
      small arcs around each spot.
    - ``rapid``: walking with fast turns and waving (RMS wave_deg at wave_hz in real time, in bursts).

    All groups add hand shake (shake_deg, shake_m at shake_hz) and rare sudden turns (jerk_rate_hz, jerk_deg).
    ``speed_scale`` speeds the whole motion up; it is drawn per sequence in its configured range.
    """
    if group not in TABLE2_GROUPS:
        raise TrajectoryError(
            f"unknown motion group {group!r} (expected one of {', '.join(TABLE2_GROUPS)}; "
            f"{SCAN_GROUP} is made by generate_scan)"
        )
    speed = rng.uniform(*motion.speed_scale)
    t = np.arange(0.0, duration + 1.0 / GENERATED_RATE_HZ, 1.0 / GENERATED_RATE_HZ)
    s = t * speed  # motion time: the same paths, run faster
    inner_lo, inner_hi = room_lo + config.wall_margin_m, room_hi - config.wall_margin_m
    centre = 0.5 * (inner_lo + inner_hi)
    half = 0.5 * (inner_hi - inner_lo)
    walk = rng.uniform(*motion.walk_speed_mps)
    yaw_rate = np.radians(rng.uniform(*motion.yaw_rate_dps))
    height = rng.uniform(*config.camera_height_m)

    if group == "aiming":
        positions, yaw, pitch = _aiming(rng, s, centre, half, walk, yaw_rate, height)
    else:
        positions, yaw, pitch = _walking(rng, s, centre, half, walk, yaw_rate, height)
        if group == "rapid":
            # Waving runs at its own rate (wave_hz in real time, not sped up), in bursts.
            envelope = min_jerk(0.5 + 0.8 * smooth_noise(rng, t, (0.05, 0.15), 2))
            amplitude = np.radians(motion.wave_deg)
            yaw = yaw + amplitude * envelope * smooth_noise(rng, t, motion.wave_hz, 2)
            pitch = pitch + 0.5 * amplitude * envelope * smooth_noise(rng, t, motion.wave_hz, 2)

    return _in_hand(rng, t, s, positions, yaw, pitch, motion).clipped(inner_lo, inner_hi)


def _in_hand(
    rng: np.random.Generator,
    t: np.ndarray,
    s: np.ndarray,
    positions: np.ndarray,
    yaw: np.ndarray,
    pitch: np.ndarray,
    motion: MotionGroupConfig,
) -> Trajectory:
    """A path held in a hand: the group's rare sudden turns, hand shake (in real time, like the waving; shake_m and
    shake_deg are the RMS of the 3-D offset and angle) and a slow roll (in motion time ``s``)."""
    per_axis = 1.0 / np.sqrt(3.0)
    bumps = jerk_offsets(rng, t, motion.jerk_rate_hz, np.radians(motion.jerk_deg))
    yaw, pitch = yaw + bumps[0], pitch + bumps[1]
    shake_hz = motion.shake_hz
    positions = positions + per_axis * motion.shake_m * np.column_stack(
        [smooth_noise(rng, t, shake_hz) for _ in range(3)]
    )
    forward = np.column_stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    roll = np.radians(3.0) * smooth_noise(rng, s, (0.1, 0.4), 2)
    shake = (
        per_axis * np.radians(motion.shake_deg) * np.column_stack([smooth_noise(rng, t, shake_hz) for _ in range(3)])
    )
    shake[:, 2] += roll
    return Trajectory(t, positions, look_rotation(forward) * Rotation.from_rotvec(shake))


# The device is held this far (m) above an object's aim point while scanning it.
SCAN_HEIGHT_ABOVE_AIM_M = 0.15
# The camera keeps this far (m) from the walls: a sweep round an object near a corner swings towards the other wall.
SCAN_WALL_MARGIN_M = 0.15


def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _look_at(positions: np.ndarray, aim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = aim - positions
    return np.arctan2(d[:, 1], d[:, 0]), np.arctan2(d[:, 2], np.linalg.norm(d[:, :2], axis=1))


def generate_scan(
    objects: list[WallObject],
    motion: MotionGroupConfig,
    scan: ScanConfig,
    room_lo: np.ndarray,
    room_hi: np.ndarray,
    duration: float,
    rng: np.random.Generator,
) -> Trajectory:
    """Handheld scanning of ``objects`` in turn, round and round until ``duration``: from ``scan.back_off_m``
    inwards of the first object's viewpoint, walk to each object's viewpoint at ``scan.distance_m`` (backing off
    from the last one towards the room's centre, across and up to the next, at the walking speed with
    ``scan.walk_accel_mps2``, the device held a little above the object's top), turning the device towards the
    object (a minimum-jerk turn at the group's yaw rate), then sweep round it from straight in front out to +arc
    and across to −arc at the sweep rate, looking at its top; look-around, hand shake and sudden turns on top.
    Distance, arc, rates and look-around are drawn once per sequence, and the rates scale with the group's
    ``speed_scale``; positions keep :data:`SCAN_WALL_MARGIN_M` from the walls."""
    if len(objects) < 2:
        raise TrajectoryError(f"a scan needs at least 2 objects, got {len(objects)}")
    speed = rng.uniform(*motion.speed_scale)
    walk = rng.uniform(*motion.walk_speed_mps) * speed
    turn = np.radians(rng.uniform(*motion.yaw_rate_dps)) * speed
    distance = rng.uniform(*scan.distance_m)
    arc = np.radians(rng.uniform(*scan.arc_deg))
    sweep = np.radians(rng.uniform(*scan.sweep_dps)) * speed
    look = np.radians(rng.uniform(*scan.look_around_deg))
    dt = 1.0 / GENERATED_RATE_HZ

    centre = 0.5 * (room_lo[:2] + room_hi[:2])

    def backed_off(obj: WallObject) -> np.ndarray:
        """``back_off_m`` from the object's viewpoint towards the room's centre: away from both walls of a corner,
        past the boxes that stand along them."""
        stand = obj.viewpoint(distance)
        inwards = (centre - stand) / max(float(np.linalg.norm(centre - stand)), 1e-9)
        return np.append(stand + scan.back_off_m * inwards, obj.aim[2] + SCAN_HEIGHT_ABOVE_AIM_M)

    position = backed_off(objects[0])
    yaw, pitch = (float(v[0]) for v in _look_at(position[None, :], objects[0].aim))
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    elapsed, k = 0.0, 0
    while elapsed < duration + dt:
        obj = objects[k % len(objects)]
        stand = np.append(obj.viewpoint(distance), obj.aim[2] + SCAN_HEIGHT_ABOVE_AIM_M)
        # The walk: back off from the last object into the room, across to this one's backed-off point and up to
        # it (the boxes stand within wall_gap + size of the walls, so the way between those points is clear),
        # turning towards it on the way.
        corners = [position] + ([backed_off(objects[(k - 1) % len(objects)])] if k else []) + [backed_off(obj), stand]
        legs = np.cumsum([0.0] + [float(np.linalg.norm(b - a)) for a, b in zip(corners[:-1], corners[1:])])
        target_yaw = float(_look_at(position[None, :], obj.aim)[0][0])
        turn_s = max(0.3, 1.875 * abs(float(_wrap(target_yaw - yaw))) / turn)
        # Sampled until the first sample that has arrived (or the turn's end, if later).
        on_grid = np.arange(0.0, _walk_seconds(legs[-1], walk, scan.walk_accel_mps2) + 2 * dt, dt)
        arrived = np.searchsorted(_walked(on_grid, legs[-1], walk, scan.walk_accel_mps2), legs[-1] - 1e-9)
        tau = np.arange(0.0, max(turn_s, dt * (arrived + 1)), dt)
        walked = _walked(tau, legs[-1], walk, scan.walk_accel_mps2)
        path = np.column_stack([np.interp(walked, legs, np.asarray(corners)[:, i]) for i in range(3)])
        aim_yaw, aim_pitch = _look_at(path, obj.aim)
        blend = min_jerk(tau / turn_s)
        parts.append((path, yaw + blend * _wrap(aim_yaw - yaw), pitch + blend * (aim_pitch - pitch)))
        # The sweep: 0 → +arc → −arc round the object's centre line.
        tau = np.arange(0.0, 3 * arc / sweep, dt)
        swept = sweep * tau
        path = np.column_stack(
            [obj.around(distance, np.where(swept < arc, swept, 2 * arc - swept)), np.full(len(tau), stand[2])]
        )
        sweep_yaw, sweep_pitch = _look_at(path, obj.aim)
        parts.append((path, sweep_yaw, sweep_pitch))
        position = path[-1]
        yaw, pitch = float(sweep_yaw[-1]), float(sweep_pitch[-1])
        elapsed += (len(parts[-2][0]) + len(tau)) * dt
        k += 1

    positions = np.vstack([p for p, _, _ in parts])
    yaws = np.unwrap(np.concatenate([y for _, y, _ in parts]))  # the parts' angles are each within ±π
    pitches = np.concatenate([q for _, _, q in parts])
    t = np.arange(len(positions)) * dt
    keep = t <= duration + dt
    t, positions, yaws, pitches = t[keep], positions[keep], yaws[keep], pitches[keep]
    yaws = yaws + look * smooth_noise(rng, t, (0.2, 0.6), 3)
    pitches = pitches + look * smooth_noise(rng, t, (0.2, 0.6), 3)
    hand = _in_hand(rng, t, t * speed, positions, yaws, pitches, motion)
    return hand.clipped(room_lo + SCAN_WALL_MARGIN_M, room_hi - SCAN_WALL_MARGIN_M)


def _walk_profile(length: float, speed: float, accel: float) -> tuple[float, float, float]:
    """The peak speed, the seconds of speeding up (and of braking) and the seconds at the peak of a walk of
    ``length``: accelerating at ``accel`` up to ``speed``, braking at ``accel`` so as to stop at its end (a
    triangle when the way is too short to reach ``speed``)."""
    peak = min(speed, np.sqrt(length * accel))
    ramp = peak / accel
    cruise = max(length / peak - ramp, 0.0) if peak > 0 else 0.0
    return peak, ramp, cruise


def _walk_seconds(length: float, speed: float, accel: float) -> float:
    _, ramp, cruise = _walk_profile(length, speed, accel)
    return 2 * ramp + cruise


def _walked(tau: np.ndarray, length: float, speed: float, accel: float) -> np.ndarray:
    """Distance walked at times ``tau`` on a walk of ``length`` (:func:`_walk_profile`)."""
    peak, ramp, cruise = _walk_profile(length, speed, accel)
    t = np.clip(tau, 0.0, 2 * ramp + cruise)
    up = 0.5 * accel * np.minimum(t, ramp) ** 2
    flat = peak * np.clip(t - ramp, 0.0, cruise)
    down = np.clip(t - ramp - cruise, 0.0, ramp)
    return np.minimum(up + flat + peak * down - 0.5 * accel * down**2, length)


def _walking(
    rng: np.random.Generator,
    s: np.ndarray,
    centre: np.ndarray,
    half: np.ndarray,
    walk: float,
    yaw_rate: float,
    height: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A loop round the room at walking speed, looking ahead and turning towards the walls."""
    radii = half[:2] * rng.uniform(0.6, 0.9, 2)
    mean_radius = float(np.mean(radii))
    direction = rng.choice([-1.0, 1.0])
    phase = rng.uniform(0, 2 * np.pi) + direction * walk * s / mean_radius
    wobble = 1.0 + 0.15 * smooth_noise(rng, s, (0.03, 0.1), 2)
    x = centre[0] + radii[0] * wobble * np.cos(phase)
    y = centre[1] + radii[1] * wobble * np.sin(phase)
    z = height + 0.015 * np.sin(2 * np.pi * 1.8 * s * walk / 0.5 + rng.uniform(0, 2 * np.pi))
    heading = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
    # Turning the head towards the walls (mostly outwards, sometimes across the room) and back.
    look_freq = rng.uniform(0.05, 0.2)
    look_amp = min(yaw_rate / (2 * np.pi * look_freq), np.radians(80))
    outward = -direction * np.radians(rng.uniform(-30, 70))
    yaw = heading + outward + look_amp * np.sin(2 * np.pi * look_freq * s + rng.uniform(0, 2 * np.pi))
    pitch = np.radians(-8.0) + np.radians(8.0) * smooth_noise(rng, s, (0.05, 0.2), 2)
    return np.column_stack([x, y, z]), yaw, pitch


def _aiming(
    rng: np.random.Generator,
    s: np.ndarray,
    centre: np.ndarray,
    half: np.ndarray,
    walk: float,
    yaw_rate: float,
    height: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Standing spots with small arcs, aiming at wall points; re-aims are minimum-jerk turns."""
    spot = centre[:2] + half[:2] * rng.uniform(-0.6, 0.6, 2)
    arc_radius = rng.uniform(0.05, 0.25)
    arc_phase = walk * s / max(arc_radius, 1e-3) * rng.choice([-1.0, 1.0])
    x = spot[0] + arc_radius * np.cos(arc_phase) + 0.3 * half[0] * smooth_noise(rng, s, (0.01, 0.03), 2)
    y = spot[1] + arc_radius * np.sin(arc_phase) + 0.3 * half[1] * smooth_noise(rng, s, (0.01, 0.03), 2)
    z = height + 0.05 * smooth_noise(rng, s, (0.05, 0.2), 2)
    positions = np.column_stack([x, y, z])

    # Aim points on the walls; each aim holds a few seconds, then a minimum-jerk turn to the next one.
    yaw = np.zeros_like(s)
    pitch = np.zeros_like(s)
    aim_yaw, aim_pitch = rng.uniform(-np.pi, np.pi), np.radians(rng.uniform(-25, 5))
    start = 0.0
    while start < s[-1]:
        hold = rng.uniform(2.0, 5.0)
        next_yaw = aim_yaw + rng.choice([-1.0, 1.0]) * np.radians(rng.uniform(30, 120))
        next_pitch = np.radians(rng.uniform(-30, 10))
        turn = max(0.4, 1.875 * abs(next_yaw - aim_yaw) / yaw_rate)
        sel = s >= start
        blend = min_jerk((s[sel] - start - hold) / turn)
        yaw[sel] = aim_yaw + blend * (next_yaw - aim_yaw)
        pitch[sel] = aim_pitch + blend * (next_pitch - aim_pitch)
        aim_yaw, aim_pitch = next_yaw, next_pitch
        start += hold + turn
    # Small scanning motion around each aim point while holding it.
    yaw += np.radians(4.0) * smooth_noise(rng, s, (0.2, 0.6), 3)
    pitch += np.radians(3.0) * smooth_noise(rng, s, (0.2, 0.6), 3)
    return positions, yaw, pitch
