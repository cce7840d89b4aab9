"""A TCP port that refuses connections for as long as a test needs it.

A port found free and then released can be taken by any process before the test dials it (a Ray worker of an
earlier test did so once, and the "refused" address answered). A socket that stays bound without listening keeps
the port ours, and the kernel refuses every connection to it."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator


@contextlib.contextmanager
def refused_port(host: str = "127.0.0.1") -> Iterator[int]:
    """Yield a port on ``host`` that is bound by this process and never listens, so connecting to it is refused
    until the block ends."""
    with socket.socket() as s:
        s.bind((host, 0))
        yield s.getsockname()[1]
