"""What a logged pose covariance says of the label: the covariance of the label's relative translation.

A pose covariance here is the monitor's (``pose_covariance.csv``, :mod:`seesys.core.session_layout`): 6×6 in the
world's axes, in ROS's order (position x, y, z, then rotation about the world's fixed x, y, z axes). The label of
frame j measures the translation from frame j − ``delta_frames`` to j (:mod:`seesys.core.labels`), so its predicted
uncertainty comes from both frames' covariances.
"""

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
