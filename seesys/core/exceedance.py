"""Equation 2's classes seen as exceedances: the class boundaries t_1 < … < t_K (the smallest error that gets n
pulses, n = 1 … K) and the class of a set of probabilities P(error ≥ t_k), as DeepSEE's ordinal head gives them.

The boundaries follow from Equation 2 itself (:func:`seesys.core.equation2.error_pulses`): N ≥ n exactly when
e ≥ β, or e ≥ α and ⌊pulses_per_metre · e⌋ ≥ n, so t_n = min(max(α, n / pulses_per_metre), β), rounded up to the
error resolution. The paper's values give 4, 8 and 12 mm.

Probabilities travel as float32 (:class:`seesys.core.messages.Estimate`): thresholds are compared in float32 too,
so a model's 0.004 read back from a message still matches Equation 2's 0.004.
"""

from __future__ import annotations

from collections.abc import Sequence
from decimal import ROUND_CEILING, Decimal

import numpy as np

from seesys.core.equation2 import PulseSettings

#: A head probability at least this counts its threshold as exceeded.
EXCEEDED = 0.5
#: Estimate logs (``seesys estimator estimate``; read by ``seesys advisory render`` and ``replay``): the column of
#: P(error ≥ t) is this prefix and t in metres (``p_ge_0.004``); ``head_class`` the head's class.
PROBABILITY_PREFIX = "p_ge_"
HEAD_CLASS_COLUMN = "head_class"


def class_boundaries_m(pulses: PulseSettings) -> tuple[float, ...]:
    """t_1 … t_K in metres (K: Equation 2's maximum pulse count), non-decreasing; equal neighbours mean an empty
    class (an α above 2 / pulses_per_metre empties class 1)."""
    eq = pulses.equation2
    alpha, beta = Decimal(repr(eq.alpha_m)), Decimal(repr(eq.beta_m))
    per_metre, resolution = Decimal(repr(eq.pulses_per_metre)), Decimal(repr(eq.error_resolution_m))
    bounds = []
    for n in range(1, pulses.max_pulses + 1):
        bound = min(max(alpha, (Decimal(n) / per_metre).quantize(resolution, rounding=ROUND_CEILING)), beta)
        bounds.append(float(bound))
    return tuple(bounds)


def same_thresholds(thresholds_m: Sequence[float], boundaries_m: Sequence[float]) -> bool:
    """Whether ``thresholds_m`` (a model's, possibly read back from float32) are exactly ``boundaries_m``."""
    return len(thresholds_m) == len(boundaries_m) and bool(
        np.array_equal(np.asarray(thresholds_m, np.float32), np.asarray(boundaries_m, np.float32))
    )


def probability_column(threshold_m: float) -> str:
    """An estimate log's column of P(error ≥ ``threshold_m``)."""
    return f"{PROBABILITY_PREFIX}{float(threshold_m)!r}"


def column_threshold(column: str) -> float | None:
    """The threshold of an estimate log's probability column, or None for another column."""
    if not column.startswith(PROBABILITY_PREFIX):
        return None
    try:
        return float(column[len(PROBABILITY_PREFIX) :])
    except ValueError:
        return None


def head_class(probabilities: np.ndarray) -> np.ndarray:
    """The class of each row of P(error ≥ t_k) (shape (..., K)): how many of its probabilities are at least
    :data:`EXCEEDED`. For monotone probabilities this is the largest k whose threshold is exceeded."""
    return np.count_nonzero(np.asarray(probabilities) >= EXCEEDED, axis=-1)
