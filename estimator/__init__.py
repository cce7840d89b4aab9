"""On the edge: synthetic data, the labelled dataset, the DeepSEE model and baselines, training, and the
estimation service."""
