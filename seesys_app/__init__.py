"""``seesys run``: the handheld advisory as one app (device, estimator, advisory), supervised, with a live view."""
