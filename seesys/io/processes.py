"""Child processes that never outlive their parent.

A supervisor that is killed (SIGKILL, a crash, a closed terminal) cannot stop its children; the kernel can. Every
SEESys child process (the ORB-SLAM3 worker, estimator workers, a study's device, advisory and mocap logger) asks
for that first thing, so nothing keeps writing into a session folder or holding a port after its parent is gone.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """Have the kernel send ``sig`` to this process when its parent dies (Linux; elsewhere nothing is done).

    Call it first thing in the child, or as a ``subprocess`` ``preexec_fn`` (with ``parent_pid = os.getpid()`` taken
    in the parent). A parent that died before the request took effect makes the process exit at once with status 1.
    Raises ``OSError`` when the kernel refuses the request.
    """
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    if os.getppid() != parent_pid:
        os._exit(1)
