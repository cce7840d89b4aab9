"""Simulated operators of the closed-loop study: a handheld motion model that walks from object to object and scans
each, and its response to the advisory's pulses.

Motion. The operator holds the device still for ``settle_s`` (SLAM initialises), then for each object walks to its
viewpoint (straight, at walking speed with an acceleration limit, turning the device towards the object at a
limited rate) and sweeps an arc round it at ``scan_distance_m``: from the viewpoint out to +arc and across to −arc
(the object is scanned when the sweep is done), looking at it with some look-around. On top: the hand shake,
sudden out-and-back turns and waving of the participant's motion group (configs/synth.toml ``[motion.*]``), as in
the dataset's renders.

Response. Every advisory buffer is heard ``audio latency`` after it is emitted (:meth:`SimulatedOperator.hear`);
after the participant's reaction delay, a buffer of N > 0 pulses sets the participant's target speed factor to
1 / (1 + slow_down_per_pulse · N) — on walking, turning, sweeping, and the sudden turns and waving — if the
participant heeds this warning (drawn with probability ``compliance`` once per warning, a run of buffers with
pulses); silence sets it back to 1. The factor follows its target with the time constant ``slow_down_s`` when
slowing and ``recovery_s`` when speeding up again. A slower operator scans more carefully and takes longer: the
advice's cost shows in time on task and mean speed.

Causality. Everything random about a participant (traits, shake, the times and sizes of sudden turns) is drawn when
the operator is made, and the heeding of warnings from a stream of its own; so the same participant moves
identically in every condition until the first warning it heeds, and the motion at time t depends only on buffers
heard before t − reaction delay.
"""

from __future__ import annotations

import bisect
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from synth.config import MotionGroupConfig
from synth.trajectories import Trajectory, jerk_offsets, look_rotation, smooth_noise

# Heard buffers older than this (s) no longer count: a stream of buffers that stopped is silence.
HEARD_FOR_S = 0.5


@dataclass(frozen=True)
class OperatorRanges:
    """``[operator]`` of configs/simulate.toml: the distributions participants' motion is drawn from."""

    motion_groups: list[str]
    motion_group_weights: list[float]
    walk_speed_mps: tuple[float, float]
    turn_rate_dps: tuple[float, float]
    scan_speed_dps: tuple[float, float]
    scan_arc_deg: tuple[float, float]
    scan_distance_m: tuple[float, float]
    look_around_deg: tuple[float, float]
    walk_accel_mps2: float
    rate_hz: float


@dataclass(frozen=True)
class ResponseRanges:
    """``[response]`` of configs/simulate.toml: how participants respond to the advisory."""

    reaction_delay_s: tuple[float, float]
    slow_down_per_pulse: tuple[float, float]
    slow_down_s: float
    recovery_s: tuple[float, float]
    compliance: tuple[float, float]


@dataclass(frozen=True)
class OperatorTraits:
    """One simulated participant."""

    motion_group: str
    walk_speed_mps: float
    turn_rate_dps: float
    scan_speed_dps: float
    scan_arc_deg: float
    scan_distance_m: float
    look_around_deg: float
    reaction_delay_s: float
    slow_down_per_pulse: float
    recovery_s: float
    compliance: float

    def record(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def draw_traits(rng: np.random.Generator, ranges: OperatorRanges, response: ResponseRanges) -> OperatorTraits:
    weights = np.asarray(ranges.motion_group_weights, float)
    group = str(rng.choice(ranges.motion_groups, p=weights / weights.sum()))

    def draw(bounds: tuple[float, float]) -> float:
        return float(rng.uniform(*bounds))

    return OperatorTraits(
        group,
        draw(ranges.walk_speed_mps),
        draw(ranges.turn_rate_dps),
        draw(ranges.scan_speed_dps),
        draw(ranges.scan_arc_deg),
        draw(ranges.scan_distance_m),
        draw(ranges.look_around_deg),
        draw(response.reaction_delay_s),
        draw(response.slow_down_per_pulse),
        draw(response.recovery_s),
        draw(response.compliance),
    )


@dataclass(frozen=True)
class Goal:
    """An object as the operator sees it: where to aim (3-D) and where to stand (x, y)."""

    aim: np.ndarray
    stand: np.ndarray


def _wrap(angle: float) -> float:
    return (angle + np.pi) % (2 * np.pi) - np.pi


class SimulatedOperator:
    """Moves in simulated time (:meth:`advance`), hears buffers (:meth:`hear`), and keeps every pose it took."""

    def __init__(
        self,
        traits: OperatorTraits,
        goals: list[Goal],
        start: np.ndarray,
        settle_s: float,
        max_s: float,
        motion: MotionGroupConfig,
        ranges: OperatorRanges,
        response: ResponseRanges,
        seed: int,
    ):
        self.traits, self.goals = traits, goals
        self._ranges, self._response = ranges, response
        self._dt = 1.0 / ranges.rate_hz
        self._settle = settle_s
        rng = np.random.default_rng([seed, 0x0BE7])
        self._heed_rng = np.random.default_rng([seed, 0x4EED])
        # Real-time signals of the whole session, drawn up front (see the module docstring: causality).
        self._grid = np.arange(0.0, max_s + 2.0, self._dt)
        per_axis = 1.0 / np.sqrt(3.0)
        self._shake_m = (
            per_axis
            * motion.shake_m
            * np.column_stack([smooth_noise(rng, self._grid, motion.shake_hz) for _ in range(3)])
        )
        self._shake_rad = (
            per_axis
            * np.radians(motion.shake_deg)
            * np.column_stack([smooth_noise(rng, self._grid, motion.shake_hz) for _ in range(3)])
        )
        jerks = jerk_offsets(rng, self._grid, motion.jerk_rate_hz, np.radians(motion.jerk_deg))
        waving = np.radians(motion.wave_deg) * np.vstack(
            [smooth_noise(rng, self._grid, motion.wave_hz, 2), 0.5 * smooth_noise(rng, self._grid, motion.wave_hz, 2)]
        )
        # Sudden turns and waving are what the advice tames: they are scaled by the speed factor.
        self._bursts = jerks + waving
        look = np.radians(traits.look_around_deg)
        self._look = look * np.vstack(
            [smooth_noise(rng, self._grid, (0.2, 0.6), 3), smooth_noise(rng, self._grid, (0.2, 0.6), 3)]
        )

        self.time = 0.0
        self._position = np.array(start, float)
        aim = goals[0].aim - self._position
        self._yaw = float(np.arctan2(aim[1], aim[0]))
        self._pitch = float(np.arctan2(aim[2], np.linalg.norm(aim[:2])))
        self._speed = 0.0
        self._goal = 0
        self._sweep = 0.0  # degrees swept round the current object (0 .. 3 arc)
        self._scanning = False
        self.factor = 1.0
        self._heard: list[tuple[float, int]] = []
        self._heeding = False
        self._warned = False
        self.reached: list[tuple[int, float]] = []
        self.warnings_heeded = 0
        self._times: list[float] = []
        self._positions: list[np.ndarray] = []
        self._rotations: list[np.ndarray] = []
        self._record()

    # -- the advisory ---------------------------------------------------------------------------------------------

    def hear(self, time: float, pulses: int) -> None:
        """A buffer of ``pulses`` pulses (0: silence) starts sounding at ``time`` (simulated seconds)."""
        self._heard.append((time, pulses))

    def _perceived(self, t: float) -> int:
        """The pulses of the newest buffer heard by t − reaction delay (0 when none is recent)."""
        moment = t - self.traits.reaction_delay_s
        newest = None
        for heard_at, pulses in reversed(self._heard):
            if heard_at <= moment:
                newest = (heard_at, pulses)
                break
        if newest is None or moment - newest[0] > HEARD_FOR_S:
            return 0
        return newest[1]

    def _update_factor(self, t: float) -> None:
        pulses = self._perceived(t)
        if pulses > 0 and not self._warned:  # a new warning: heeded or not, once
            self._warned = True
            self._heeding = bool(self._heed_rng.uniform() < self.traits.compliance)
            self.warnings_heeded += int(self._heeding)
        elif pulses == 0:
            self._warned = self._heeding = False
        target = 1.0 / (1.0 + self.traits.slow_down_per_pulse * pulses) if self._heeding else 1.0
        tau = self._response.slow_down_s if target < self.factor else self.traits.recovery_s
        self.factor += (target - self.factor) * (1.0 - np.exp(-self._dt / tau))

    # -- motion ---------------------------------------------------------------------------------------------------

    @property
    def done(self) -> bool:
        """Every object scanned."""
        return self._goal >= len(self.goals)

    def _turn_towards(self, yaw: float, pitch: float) -> None:
        step = np.radians(self.traits.turn_rate_dps) * self.factor * self._dt
        self._yaw += float(np.clip(_wrap(yaw - self._yaw), -step, step))
        self._pitch += float(np.clip(pitch - self._pitch, -step, step))

    def _aim_at(self, point: np.ndarray) -> tuple[float, float]:
        d = point - self._position
        return float(np.arctan2(d[1], d[0])), float(np.arctan2(d[2], np.linalg.norm(d[:2])))

    def _step(self) -> None:
        t = self.time + self._dt
        self._update_factor(t)
        if t >= self._settle and not self.done:
            goal = self.goals[self._goal]
            if not self._scanning:
                self._walk(goal)
            else:
                self._scan(goal, t)
        self.time = t
        self._record()

    def _walk(self, goal: Goal) -> None:
        to_go = goal.stand - self._position[:2]
        distance = float(np.linalg.norm(to_go))
        accel = self._ranges.walk_accel_mps2
        wanted = min(self.traits.walk_speed_mps * self.factor, np.sqrt(2 * accel * distance))
        self._speed = float(np.clip(wanted, self._speed - accel * self._dt, self._speed + accel * self._dt))
        move = min(self._speed * self._dt, distance)
        if distance > 0:
            self._position[:2] += to_go / distance * move
        # Height follows the aim: the device held a little above the object's top.
        self._position[2] += np.clip(goal.aim[2] + 0.15 - self._position[2], -0.3 * self._dt, 0.3 * self._dt)
        self._turn_towards(*self._aim_at(goal.aim))
        if distance - move < 0.02:
            self._scanning, self._sweep, self._speed = True, 0.0, 0.0

    def _scan(self, goal: Goal, t: float) -> None:
        arc = self.traits.scan_arc_deg
        self._sweep += self.traits.scan_speed_dps * self.factor * self._dt
        # 0 → +arc → −arc
        s = min(self._sweep, 3 * arc)
        angle = s if s < arc else 2 * arc - s
        offset = goal.stand - goal.aim[:2]
        c, sn = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        self._position[:2] = goal.aim[:2] + np.array([c * offset[0] - sn * offset[1], sn * offset[0] + c * offset[1]])
        k = self._index(t)
        yaw, pitch = self._aim_at(goal.aim)
        self._turn_towards(yaw + self._look[0, k], pitch + self._look[1, k])
        if self._sweep >= 3 * arc:
            self.reached.append((self._goal + 1, t))
            self._goal += 1
            self._scanning = False

    def _index(self, t: float) -> int:
        return min(int(round(t / self._dt)), len(self._grid) - 1)

    def _record(self) -> None:
        k = self._index(self.time)
        bursts = self.factor * self._bursts[:, k]
        yaw, pitch = self._yaw + bursts[0], self._pitch + bursts[1]
        forward = np.array([[np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)]])
        rotation = look_rotation(forward) * Rotation.from_rotvec(self._shake_rad[k])
        self._times.append(self.time)
        self._positions.append(self._position + self._shake_m[k])
        self._rotations.append(rotation.as_quat()[0])

    def advance(self, until: float) -> None:
        """Move on to simulated time ``until`` (or the end of the signals drawn for ``max_s``)."""
        end = min(until, self._grid[-1])
        while self.time + self._dt <= end + 1e-9:
            self._step()

    def trajectory(self, since: float = -np.inf) -> Trajectory:
        """The poses taken from ``since`` (one sample earlier, so that ``since`` itself is covered) to now."""
        first = min(max(bisect.bisect_left(self._times, since) - 1, 0), len(self._times) - 2)
        return Trajectory(
            np.asarray(self._times[first:]),
            np.asarray(self._positions[first:]),
            Rotation.from_quat(np.asarray(self._rotations[first:])),
        )
