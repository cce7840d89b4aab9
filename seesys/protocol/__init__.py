"""The wire protocol every part speaks: message codec, RTS schema, tracking states, model windows and the
ZeroMQ socket helpers. Device, estimator, advisory and study import it from here; none reaches into another part
for it."""
