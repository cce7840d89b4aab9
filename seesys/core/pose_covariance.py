"""What a logged pose covariance says of the label: the covariance of the label's relative translation.

A pose covariance here is the monitor's (``pose_covariance.csv``, :mod:`seesys.core.session_layout`): 6×6 in the
world's axes, in ROS's order (position x, y, z, then rotation about the world's fixed x, y, z axes). The label of
frame j measures the translation from frame j − ``delta_frames`` to j (:mod:`seesys.core.labels`), so its predicted
uncertainty comes from both frames' covariances. A model's estimate of that error gives the covariance its size
(:func:`scaled_to_error`), the pose fit's geometry its shape.
"""

from collections.abc import Mapping

import numpy as np


def relative_translation_covariance(
    covariance_i: np.ndarray, covariance_j: np.ndarray, position_i: np.ndarray, position_j: np.ndarray
) -> np.ndarray:
    """The 3×3 covariance (world axes) of the error of the translation from pose i to pose j — the label's pair —
    from their 6×6 world-axes covariances, taken as independent.

    With world-axes perturbations (c + δc, exp(δθ) R), the relative translation Rᵢᵀ(cⱼ − cᵢ) moves by
    Rᵢᵀ(δcⱼ − δcᵢ + [cⱼ − cᵢ]× δθᵢ): the rotation error of the first pose swings the path travelled since. Its norm,
    and so the trace returned here, does not depend on the axes it is written in."""
    lever = np.asarray(position_j, np.float64) - np.asarray(position_i, np.float64)
    x, y, z = lever
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    from_i = np.hstack([-np.eye(3), cross])
    from_j = np.hstack([np.eye(3), np.zeros((3, 3))])
    return from_i @ covariance_i @ from_i.T + from_j @ covariance_j @ from_j.T


def pair_covariance(
    covariances: Mapping[int, np.ndarray], positions: Mapping[int, np.ndarray], j: int, delta: int
) -> np.ndarray | None:
    """The 3×3 covariance of frame j's pair (j − ``delta``, j), from the frames' 6×6 covariances and positions
    (by frame index); None unless both frames have both."""
    i = j - delta
    if any(k not in covariances or k not in positions for k in (i, j)):
        return None
    return relative_translation_covariance(covariances[i], covariances[j], positions[i], positions[j])


def translation_pair_covariance(translation_i: np.ndarray, translation_j: np.ndarray) -> np.ndarray:
    """The label pair's 3×3 covariance from the two frames' translation blocks alone (as the feature stream carries
    them): :func:`relative_translation_covariance` without the first pose's rotation swinging the path travelled
    since, which needs its rotation block."""
    return np.asarray(translation_i, np.float64) + np.asarray(translation_j, np.float64)


def scaled_to_error(covariance: np.ndarray, pair: np.ndarray, error_m: float) -> np.ndarray | None:
    """Frame j's 6×6 ``covariance`` scaled so that its pair's σ (√trace of ``pair``, the 3×3 covariance of the
    label's relative translation ending at j: :func:`pair_covariance`) is the estimated error ``error_m``: the shape
    from the pose fit's geometry, the size from the estimate. A label then lies within this covariance's 1σ (2σ)
    exactly when it is at most the estimate (twice the estimate). None where the estimate is not a finite positive
    number or the pair has no positive trace."""
    trace = float(np.trace(pair))
    if not (np.isfinite(error_m) and error_m > 0 and np.isfinite(trace) and trace > 0):
        return None
    return np.asarray(covariance, np.float64) * (error_m * error_m / trace)
