"""How many pulses a buffer holds: Equation 2 of the paper for pose-error estimates, and the study's rotation rule.

Both rules compare a real-valued input against thresholds and floor a product. In binary floating point the mean
of ten 0.012 m estimates is 0.011999999999999999, a hair below β, which would drop a pulse exactly at a
threshold. The input is therefore rounded to a configured resolution (1 nm, 1e-6 °/s)
and everything after that is exact decimal arithmetic on the shortest decimal form of each number, so the
thresholds behave as written: ``e = 0.004`` gives 1 pulse, ``0.0039999`` gives 0, ``0.008`` gives 2, ``0.012`` gives
3 and ``0.011999`` gives 2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import ROUND_FLOOR, ROUND_HALF_EVEN, Decimal


@dataclass(frozen=True)
class Equation2Config:
    alpha_m: float
    beta_m: float
    pulses_per_metre: float
    pulse_s: float
    interval_s: float
    error_resolution_m: float


@dataclass(frozen=True)
class RotationConfig:
    degrees_per_step: float
    steps_below_first_pulse: int
    speed_resolution_deg_s: float
    max_frame_gap_s: float


def _decimal(x: float) -> Decimal:
    """The shortest decimal that reads back as ``x`` (``0.1`` → ``Decimal('0.1')``, not its binary expansion)."""
    return Decimal(repr(float(x)))


def _quantise(value: float, resolution: float) -> Decimal:
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"the input must be a finite non-negative number, got {value}")
    return _decimal(value).quantize(_decimal(resolution), rounding=ROUND_HALF_EVEN)


def _floor(x: Decimal) -> int:
    return int(x.to_integral_value(rounding=ROUND_FLOOR))


def max_pulses(eq: Equation2Config, buffer_s: float) -> int:
    """Equation 2's top case, ⌊buffer / (p + i)⌋: as many pulses as fit in one buffer (3 for the paper's values)."""
    return _floor(_decimal(buffer_s) / (_decimal(eq.pulse_s) + _decimal(eq.interval_s)))


def error_pulses(error_m: float, eq: Equation2Config, buffer_s: float) -> int:
    """Equation 2: the number of pulses for a (moving-average) pose-error estimate in metres."""
    e = _quantise(error_m, eq.error_resolution_m)
    if e < _decimal(eq.alpha_m):
        return 0
    if e < _decimal(eq.beta_m):
        return min(_floor(_decimal(eq.pulses_per_metre) * e), max_pulses(eq, buffer_s))
    return max_pulses(eq, buffer_s)


def rotation_pulses(speed_deg_s: float, rot: RotationConfig, eq: Equation2Config, buffer_s: float) -> int:
    """The rotation baseline: N = max(⌊θ/50°⌋ − 1, 0), capped at Equation 2's maximum; θ in degrees/second."""
    theta = _quantise(speed_deg_s, rot.speed_resolution_deg_s)
    steps = _floor(theta / _decimal(rot.degrees_per_step)) - rot.steps_below_first_pulse
    return min(max(steps, 0), max_pulses(eq, buffer_s))


@dataclass(frozen=True)
class PulseSettings:
    """Equation 2 with the advisory timing its pulse counts depend on: ``buffer_s`` (how many pulses fit in one
    buffer) and ``window_s`` (the moving mean the estimates are averaged over before Equation 2)."""

    equation2: Equation2Config
    buffer_s: float
    window_s: float

    @property
    def max_pulses(self) -> int:
        return max_pulses(self.equation2, self.buffer_s)

    def pulses(self, error_m: float) -> int:
        """Equation 2's pulse count for a (moving-mean) error estimate in metres."""
        return error_pulses(error_m, self.equation2, self.buffer_s)
