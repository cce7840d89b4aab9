"""Child processes that never outlive their parent, and signals that stop a process's loop.

A supervisor that is killed (SIGKILL, a crash, a closed terminal) cannot stop its children; the kernel can. Every
SEESys child process (the ORB-SLAM3 worker, estimator workers, a study's device, advisory and mocap logger, a JACK
dummy server) asks for that first thing, so nothing keeps writing into a session folder or holding a port after its
parent is gone.

The request is made after ``exec``, never in a ``subprocess`` ``preexec_fn``: Python code run between ``fork`` and
``exec`` in a parent with threads (a supervisor has several) can deadlock on a lock another thread held at the fork,
leaving a child that never asked to die with its parent. Programs started by ``subprocess`` go through
:func:`dying_with_parent`, a launcher that asks and then execs them; Python processes of ours that are ``spawn``-ed
call :func:`die_with_parent` themselves.

Run as ``python -m seesys.io.processes PARENT_PID SIGNAL PROGRAM [ARGS...]``, this module is that launcher.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
from collections.abc import Iterator

PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """Have the kernel send ``sig`` to this process when its parent dies (Linux; elsewhere nothing is done).

    Call it first thing in the child, with ``parent_pid`` taken in the parent. A parent that died before the request
    took effect makes the process exit at once with status 1. Raises ``OSError`` when the kernel refuses the request.
    """
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    if os.getppid() != parent_pid:
        os._exit(1)


def dying_with_parent(command: list[str], sig: int = signal.SIGTERM) -> list[str]:
    """``command`` run so that the kernel sends it ``sig`` when this process dies: for ``subprocess.Popen``.

    The launcher is a short Python process that makes the request and execs ``command`` in its place (same pid); a
    program that cannot be executed ends it with status 127 and the reason on its stderr."""
    return [sys.executable, "-m", "seesys.io.processes", str(os.getpid()), str(int(sig)), *command]


@contextlib.contextmanager
def stop_on_signals(*signals: int) -> Iterator[threading.Event]:
    """Within the block, SIGTERM and SIGINT (or ``signals``) set the event it yields instead of ending the process,
    so its loop ends and its logs are closed; the previous handlers come back after it. Enter it in the main thread.

    The handler only writes a byte to a pipe; a thread reads it and sets the event. The handler runs in the main
    thread between two bytecodes, possibly while that thread holds the event's lock (inside ``wait``) or the
    threading module's (starting a thread): setting the event or starting a thread there could deadlock.
    """
    stop = threading.Event()
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)

    def set_when_told() -> None:
        if os.read(read_end, 1):  # b"": the block ended and closed the pipe
            stop.set()

    def told(signum: int, frame: object) -> None:
        with contextlib.suppress(BlockingIOError):  # a pipe full of earlier signals: the event is being set
            os.write(write_end, b"\0")

    reader = threading.Thread(target=set_when_told, name="stop-on-signals", daemon=True)
    reader.start()
    previous = {sig: signal.signal(sig, told) for sig in signals or (signal.SIGTERM, signal.SIGINT)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            # None: a handler installed outside Python, which cannot be put back; the default instead.
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        os.close(write_end)
        reader.join()
        os.close(read_end)


def _launch(argv: list[str]) -> None:
    parent_pid, sig, *command = argv
    die_with_parent(int(parent_pid), int(sig))
    try:
        os.execvp(command[0], command)
    except OSError as e:
        sys.stderr.write(f"cannot run {command[0]}: {e.strerror}\n")
        os._exit(127)


if __name__ == "__main__":
    _launch(sys.argv[1:])
