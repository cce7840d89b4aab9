"""The three advisory conditions of the user study (paper §7.3) and what each one listens to.

- ``seesys``: Equation 2 on the moving average of the pose-error estimates (metres).
- ``rotation``: the rotation rule on the moving average of the device's angular speed (°/s), from its features.
- ``none``: silent; it computes and logs what ``seesys`` would have played, and its buffers hold no pulses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from advisory.config import AdvisoryConfig
from advisory.rotation import RotationSpeed
from seesys.core.equation2 import error_pulses, rotation_pulses
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
    sample: Callable[[Estimate | FeatureFrame], float | None]  # a received message → input value (or none)
    rule: Callable[[float], int]  # moving average → N
    unit: str


def _estimate_error(message: Estimate | FeatureFrame) -> float | None:
    return message.error_m if isinstance(message, Estimate) else None


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

        def sample(message: Estimate | FeatureFrame) -> float | None:
            return speed.update(message) if isinstance(message, FeatureFrame) else None

        return ConditionInput(network.features_endpoint, _subscription(FEATURE_TOPIC, device), sample,
                              pulse_rule(condition, cfg), "deg/s")
    return ConditionInput(network.estimates_endpoint, _subscription(ESTIMATE_TOPIC, device), _estimate_error,
                          pulse_rule(condition, cfg), "m")
