"""Thin I/O on top of :mod:`seesys.core`: settings files, resource folders, ZeroMQ transport, child processes,
and the session folder's files (trajectories, logs, manifests, RTS and PSD logs, labels of a recorded session).

Every part may import it; it imports nothing but :mod:`seesys.core` (docs/architecture.md).
"""
