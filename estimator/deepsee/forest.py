"""The random-forest baseline of Table 3 (Ali et al. 2023, the offline state of the art): scikit-learn's
``RandomForestRegressor`` on per-window statistics of the normalised RTS channels (mean, standard deviation, minimum,
maximum and last value of each channel: the 1-D global pooling of their characterisation series, here over the
30-row window). It regresses the same transformed label as DeepSEE and sees the RTS window only. No PyTorch here:
exporting and serving a forest does not load it.
"""

from __future__ import annotations

import numpy as np
from sklearn.ensemble import RandomForestRegressor

from estimator.deepsee.config import RandomForestConfig


def window_statistics(rts: np.ndarray) -> np.ndarray:
    """(N, T, C) normalised windows → (N, 5·C) features: mean, std, min, max, last value per channel."""
    return np.concatenate([rts.mean(axis=1), rts.std(axis=1), rts.min(axis=1), rts.max(axis=1), rts[:, -1]], axis=1)


def fit_random_forest(
    rts: np.ndarray, targets: np.ndarray, config: RandomForestConfig, seed: int, jobs: int
) -> RandomForestRegressor:
    """The forest on the :func:`window_statistics` of (N, T, C) normalised windows (:func:`fit_forest`)."""
    return fit_forest(window_statistics(rts), targets, config, seed, jobs)


def fit_forest(
    features: np.ndarray, targets: np.ndarray, config: RandomForestConfig, seed: int, jobs: int
) -> RandomForestRegressor:
    """Fit on the (N, F) ``features`` of at most ``max_train_samples`` windows (a seeded subset). Serve with
    ``n_jobs=1``: at batch 1 the joblib dispatch of more jobs costs more than the trees."""
    index = np.arange(len(features))
    if 0 < config.max_train_samples < len(features):
        index = np.sort(np.random.default_rng(seed).choice(len(features), config.max_train_samples, replace=False))
    forest = RandomForestRegressor(
        n_estimators=config.trees,
        min_samples_leaf=config.min_samples_leaf,
        max_features=config.max_features,
        n_jobs=jobs,
        random_state=seed,
    )
    forest.fit(features[index], targets[index])
    forest.set_params(n_jobs=1)
    return forest
