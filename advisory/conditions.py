"""The three advisory conditions of the user study (paper §7.3) and what each one listens to.

- ``seesys``: Equation 2 on the moving average of the pose-error estimates (metres); or, where the estimates carry
  a model's ordinal head for exactly Equation 2's class boundaries and ``[pulses] pulses_from = "head"``, the head's
  class of its probabilities averaged over the same window (``advisory.scheduler``).
- ``rotation``: the rotation rule on the moving average of the device's angular speed (°/s), from its features.
- ``none``: silent; it computes and logs what ``seesys`` would have played, and its buffers hold no pulses.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum

from advisory.config import HEAD_SOURCE, AdvisoryConfig
from advisory.rotation import RotationSpeed
from advisory.scheduler import Reading
from seesys.core.equation2 import PulseSettings, error_pulses, rotation_pulses
from seesys.core.exceedance import class_boundaries_m, same_thresholds
from seesys.core.messages import ESTIMATE_TOPIC, FEATURE_TOPIC, Estimate, FeatureFrame, topic
from seesys.io.network import NetworkConfig


class Condition(str, Enum):
    SEESYS = "seesys"
    ROTATION = "rotation"
    NONE = "none"

    @property
    def audible(self) -> bool:
        return self is not Condition.NONE


@dataclass(frozen=True)
class ConditionInput:
    """Where a condition's input comes from and how it becomes a number of pulses."""

    endpoint: str
    topic: bytes
    sample: Callable[[Estimate | FeatureFrame], Reading | None]  # a received message → input (or none)
    rule: Callable[[float], int]  # moving average → N
    unit: str
    rule_name: str  # how advisory.csv names the rule: "estimate" (Equation 2) or "rotation"


def head_rule(cfg: AdvisoryConfig) -> Callable[[Sequence[float]], bool]:
    """Whether a head of these thresholds decides N: ``pulses_from = "head"`` and the thresholds are exactly
    Equation 2's class boundaries (a head of other thresholds, or none, leaves Equation 2 to the estimate)."""
    boundaries = class_boundaries_m(PulseSettings(cfg.equation2, cfg.timing.buffer_s, cfg.timing.window_s))
    use_head = cfg.pulses.pulses_from == HEAD_SOURCE
    return lambda thresholds_m: use_head and same_thresholds(thresholds_m, boundaries)


def estimate_reading(cfg: AdvisoryConfig) -> Callable[[Estimate | FeatureFrame], Reading | None]:
    """An estimate → its error and, where :func:`head_rule` allows, its head's probabilities."""
    decides = head_rule(cfg)

    def sample(message: Estimate | FeatureFrame) -> Reading | None:
        if not isinstance(message, Estimate):
            return None
        if decides([e.threshold_m for e in message.head]):
            return Reading(message.error_m, tuple(e.probability for e in message.head))
        return Reading(message.error_m)

    return sample


def pulse_rule(condition: Condition, cfg: AdvisoryConfig) -> Callable[[float], int]:
    """The condition's moving average → N (``none`` applies Equation 2, to log what it would have played)."""
    buffer_s = cfg.timing.buffer_s
    if condition is Condition.ROTATION:
        return lambda theta: rotation_pulses(theta, cfg.rotation, cfg.equation2, buffer_s)
    return lambda e: error_pulses(e, cfg.equation2, buffer_s)


def _subscription(kind: bytes, device_id: str) -> bytes:
    """The exact topic of one device, or the kind's prefix (every device) for an empty ``device_id``."""
    return topic(kind, device_id) if device_id else kind


def condition_input(condition: Condition, cfg: AdvisoryConfig, network: NetworkConfig) -> ConditionInput:
    device = cfg.timing.listen_to_device
    if condition is Condition.ROTATION:
        speed = RotationSpeed(cfg.rotation)

        def sample(message: Estimate | FeatureFrame) -> Reading | None:
            speed_deg_s = speed.update(message) if isinstance(message, FeatureFrame) else None
            return None if speed_deg_s is None else Reading(speed_deg_s)

        return ConditionInput(
            network.features_endpoint,
            _subscription(FEATURE_TOPIC, device),
            sample,
            pulse_rule(condition, cfg),
            "deg/s",
            "rotation",
        )
    return ConditionInput(
        network.estimates_endpoint,
        _subscription(ESTIMATE_TOPIC, device),
        estimate_reading(cfg),
        pulse_rule(condition, cfg),
        "m",
        "estimate",
    )
