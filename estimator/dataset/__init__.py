"""The labelled training dataset: build it, read it, split it, report on its labels.

- :mod:`~estimator.dataset.config`: ``configs/dataset.toml``.
- :mod:`~estimator.dataset.build`: render a batch, then run ORB-SLAM3 + RTS monitor on every sequence × mode ×
  trial (one at a time, never while rendering), label every frame and write one run of samples each; resumable.
  Its renders and runs are jobs (:mod:`estimator.jobs`): here, or as Ray tasks with ``--ray`` (docs/ray.md).
- :mod:`~estimator.dataset.store`: the on-disk layout of a run (memory-mapped ``.npy`` + CSV) and the lazy
  reader :class:`~estimator.dataset.store.DatasetReader`.
- :mod:`~estimator.dataset.splits`: grouped cross-validation by trajectory and motion group, held-out
  environments, no trajectory in two parts.
- :mod:`~estimator.dataset.report`: label distribution against the targets, feature-vs-error correlations.
- :mod:`~estimator.dataset.sample`: regenerate the embedded demo sample and vocabulary.

docs/dataset.md describes the layout and the choices.
"""
