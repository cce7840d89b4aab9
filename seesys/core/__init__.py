"""The concepts every part of SEESys shares, as pure code: values in, values out.

Nothing here reads or writes files, opens sockets, loads settings or plots (numpy, scipy and evo's own pure core only):
the RTS schema, the PSD layout, camera intrinsics and camera normalisation, model windows, the wire messages and their
codec, Equation 2, the pose-error definition, poses, and the session folder's names and records. Loading settings and
reading or writing files is :mod:`seesys.io`'s job; the parts (``slam_monitor``, ``advisory``, ``estimator``, ``study``,
``analysis``) build on both, and the app and command line sit on top (docs/architecture.md).
"""
