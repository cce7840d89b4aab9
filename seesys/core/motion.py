"""The motion statistic: how unevenly the camera moves, from its frame-to-frame translation.

One definition for the motion yardstick every estimate is judged beside (``estimator.deepsee.references``: windows of
relative translation, metres per frame) and for the advisory's ``motion`` condition (``advisory.motion``: the
translation velocity of the frames of the last second, metres per second): the spread of the displacements about
their mean, ``sqrt(Σ_axis var(d_axis))``. A steady walk gives a small value, hand shake, sudden turns and waving a
large one; in our data it ranks the pose error about as well as any model does (docs/estimator.md, the reference rows).
"""

from __future__ import annotations

import numpy as np


def translation_spread(displacements: np.ndarray) -> np.ndarray:
    """(..., T, 3) displacements (or velocities) → (...,) ``sqrt(Σ_axis var over T)``, in their unit."""
    d = np.asarray(displacements, np.float64)
    return np.sqrt(np.sum(np.var(d, axis=-2), axis=-1))
