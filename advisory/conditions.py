"""The advisory conditions of a user study and what each one listens to.

The paper's three (§7.3):

- ``seesys``: Equation 2 on the moving average of the pose-error estimates (metres); or, where the estimates carry
  a model's ordinal head for exactly Equation 2's class boundaries and ``[pulses] pulses_from = "head"``, the head's
  class of its probabilities averaged over the same window (``advisory.scheduler``).
- ``rotation``: the rotation rule on the moving average of the device's angular speed (°/s), from its features.
- ``none``: silent; it computes and logs what ``seesys`` would have played, and its buffers hold no pulses.

And the controls that tell an advisory's information from its pacing:

- ``motion``: the motion statistic of the device's features (``advisory.motion``, m/s) against thresholds set so
  that it pulses as often as ``seesys`` did in pilot sessions (``[motion]`` of advisory.toml).
- ``yoked`` (simulation only): the pulse sequence another participant's ``seesys`` session played, at the same times
  from the task's start: the same amount and rhythm of sound, unrelated to this session's error.
- ``oracle`` (simulation only): Equation 2 on the true error (the renderer's ground truth) at the estimator's latency:
  the best any estimate could do with this rule.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum

from advisory.config import HEAD_SOURCE, AdvisoryConfig
from advisory.motion import MotionStatistic
from advisory.rotation import RotationSpeed
from advisory.scheduler import Reading
from seesys.core.equation2 import PulseSettings, error_pulses, max_pulses, rotation_pulses
from seesys.core.errors import SeesysError
from seesys.core.exceedance import class_boundaries_m, same_thresholds
from seesys.core.messages import ESTIMATE_TOPIC, FEATURE_TOPIC, Estimate, FeatureFrame, topic
from seesys.io.network import NetworkConfig


class Condition(str, Enum):
    SEESYS = "seesys"
    ROTATION = "rotation"
    NONE = "none"
    MOTION = "motion"
    YOKED = "yoked"
    ORACLE = "oracle"

    @property
    def audible(self) -> bool:
        return self is not Condition.NONE

    @property
    def hears_features(self) -> bool:
        """Whether its input is the device's feature stream (the motion rules) rather than the estimates."""
        return self in (Condition.ROTATION, Condition.MOTION)

    @property
    def live(self) -> bool:
        """Whether a live advisory can run it (``yoked`` and ``oracle`` need another session or the ground truth)."""
        return self not in (Condition.YOKED, Condition.ORACLE)


#: The conditions a live advisory (and so a study with people) can run.
LIVE_CONDITIONS = tuple(c.value for c in Condition if c.live)


def threshold_pulses(value: float, thresholds: Sequence[float], most: int) -> int:
    """How many of the ascending ``thresholds`` ``value`` reaches, at most ``most``."""
    return min(bisect.bisect_right(list(thresholds), value), most)


@dataclass(frozen=True)
class ConditionInput:
    """Where a live condition's input comes from and what a received message gives (its rule and rule name are the
    advice step's: :func:`pulse_rule`, :func:`rule_name`)."""

    endpoint: str
    topic: bytes
    sample: Callable[[Estimate | FeatureFrame], Reading | None]  # a received message → input (or none)


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
    """The condition's moving average → N (``none`` applies Equation 2, to log what it would have played; ``oracle``
    applies it to the true error). Raises :class:`SeesysError` for ``yoked``, which replays pulses and has no rule."""
    buffer_s = cfg.timing.buffer_s
    if condition is Condition.ROTATION:
        return lambda theta: rotation_pulses(theta, cfg.rotation, cfg.equation2, buffer_s)
    if condition is Condition.MOTION:
        most = max_pulses(cfg.equation2, buffer_s)
        return lambda speed: threshold_pulses(speed, cfg.motion.thresholds_m_s, most)
    if condition is Condition.YOKED:
        raise SeesysError("the yoked condition replays another session's pulses: it has no pulse rule")
    return lambda e: error_pulses(e, cfg.equation2, buffer_s)


#: How advisory.csv names the rule of a condition's buffers (``pulses_from``, where no head decided).
RULE_NAMES = {Condition.ROTATION: "rotation", Condition.MOTION: "motion", Condition.ORACLE: "truth"}


def rule_name(condition: Condition) -> str:
    return RULE_NAMES.get(condition, "estimate")


def _subscription(kind: bytes, device_id: str) -> bytes:
    """The exact topic of one device, or the kind's prefix (every device) for an empty ``device_id``."""
    return topic(kind, device_id) if device_id else kind


def feature_reading(condition: Condition, cfg: AdvisoryConfig) -> Callable[[Estimate | FeatureFrame], Reading | None]:
    """A feature frame → the rotation speed (°/s, ``rotation``) or the motion statistic (m/s, ``motion``)."""
    statistic = RotationSpeed(cfg.rotation) if condition is Condition.ROTATION else MotionStatistic(cfg.motion)

    def sample(message: Estimate | FeatureFrame) -> Reading | None:
        value = statistic.update(message) if isinstance(message, FeatureFrame) else None
        return None if value is None else Reading(value)

    return sample


def condition_input(condition: Condition, cfg: AdvisoryConfig, network: NetworkConfig) -> ConditionInput:
    """Where a live advisory of ``condition`` listens and what it makes of it; :class:`SeesysError` for a condition
    that only a simulation can run."""
    if not condition.live:
        raise SeesysError(
            f"the {condition.value} condition runs only in a simulated study (seesys study simulate): it needs "
            "another session's pulses or the ground truth"
        )
    device = cfg.timing.listen_to_device
    if condition.hears_features:
        return ConditionInput(
            network.features_endpoint, _subscription(FEATURE_TOPIC, device), feature_reading(condition, cfg)
        )
    return ConditionInput(network.estimates_endpoint, _subscription(ESTIMATE_TOPIC, device), estimate_reading(cfg))
