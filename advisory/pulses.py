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
from decimal import ROUND_FLOOR, ROUND_HALF_EVEN, Decimal

from advisory.config import Equation2Config, RotationConfig


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
