"""Runs a device session in a child process and turns any way it can end into a result or a clear error.

ORB-SLAM3 can take its process down: it calls ``exit`` on a settings problem and segfaults on some bad inputs.
The session therefore runs in a ``spawn``-ed child (:func:`worker_main`) whose console output (ORB-SLAM3 prints
a lot) goes to ``orbslam3.log`` in the session folder. The child reports progress and its outcome on a queue;
the parent maps every ending to a :class:`SessionResult` or a :class:`SeesysError`, records crashes in
``session.json``, and the files the child already wrote stay as they are. The child never outlives the
parent: if the parent is killed, the kernel kills the child too (Linux), instead of leaving an ORB-SLAM3
process behind that hangs on a queue nobody reads.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import signal
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from seesys.core import session_layout
from seesys.core.errors import SeesysError
from seesys.io import session_files
from seesys.io.processes import die_with_parent
from slam_monitor.device_worker import (
    ProgressCallback,
    SessionOptions,
    SessionResult,
    run_device_session,
)
from slam_monitor.orbslam_settings import load_slam_config

POLL_S = 0.2
# ORB-SLAM3 calls exit(-1) when a required setting is missing.
ORBSLAM_EXIT_STATUS = 255
# prctl(2) option: the signal this process gets when the thread that started it dies.


class WorkerCrash(SeesysError):
    """The device worker process ended without reporting an outcome (ORB-SLAM3 exited or crashed)."""


@dataclass(frozen=True)
class _Failed:
    message: str


@dataclass(frozen=True)
class _Finished:
    result: SessionResult


def _redirect_console(log_path: Path) -> None:
    """Send this process's stdout and stderr, including the C++ library's, to ``log_path`` (started afresh)."""
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


def _interrupt_once(signum: int, frame: object) -> None:
    # The first SIGINT interrupts the session; later ones (the supervisor forwards the one it got, which a
    # terminal's Ctrl-C may also have sent here) must not cut short the closing of its files.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def worker_main(options: SessionOptions, events: multiprocessing.Queue, parent_pid: int) -> None:
    """Child-process entry point: run the session, reporting progress and the outcome on ``events``."""
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, _interrupt_once)
    try:
        options.out_dir.mkdir(parents=True, exist_ok=True)
        _redirect_console(options.out_dir / session_layout.SLAM_LOG)
    except OSError as e:
        events.put(_Failed(f"cannot write the session folder {options.out_dir}: {e.strerror}"))
        return
    try:
        result = run_device_session(options, progress=events.put)
    except SeesysError as e:
        events.put(_Failed(str(e)))
    except KeyboardInterrupt:
        events.put(_Failed("interrupted"))
    except Exception as e:  # a bug: keep the traceback in the log, report one line
        traceback.print_exc()
        events.put(
            _Failed(
                f"internal error in the device worker: {type(e).__name__}: {e} (traceback in "
                f"{options.out_dir / session_layout.SLAM_LOG})"
            )
        )
    else:
        events.put(_Finished(result))
    finally:
        sys.stdout.flush()
        sys.stderr.flush()


def _last_log_line(out_dir: Path) -> str:
    path = out_dir / session_layout.SLAM_LOG
    if not path.exists():
        return ""
    lines = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
    return lines[-1] if lines else ""


def frames_logged(out_dir: Path) -> int:
    """Frames the session in ``out_dir`` has logged so far (rows of ``frames.csv``)."""
    path = out_dir / session_layout.FRAMES_CSV
    if not path.exists():
        return 0
    with open(path, "rb") as f:
        return max(0, sum(1 for _ in f) - 1)  # minus the header


def _crash_message(exit_code: int | None, frame_index: int, out_dir: Path) -> str:
    if exit_code is None:  # not joined: cannot happen after join(), said rather than assumed
        how = "ended without an exit status"
    elif exit_code < 0:
        how = f"crashed (signal {-exit_code}, {signal.Signals(-exit_code).name})"
    elif exit_code == ORBSLAM_EXIT_STATUS:
        how = f"exited with status {exit_code}"
    else:
        how = f"ended with status {exit_code}"
    return _ending_message(how, frame_index, out_dir)


def _ending_message(how: str, frame_index: int, out_dir: Path) -> str:
    said = _last_log_line(out_dir)
    said = f' after printing "{said}"' if said else ""
    if frame_index == 0:
        return f"ORB-SLAM3 {how}{said} before the first frame; see {out_dir / session_layout.SLAM_LOG}"
    return (
        f"ORB-SLAM3 {how}{said} at frame {frame_index}; the session files up to frame {frame_index - 1} "
        f"are kept in {out_dir}"
    )


def run_supervised_session(options: SessionOptions, progress: ProgressCallback | None = None) -> SessionResult:
    """Run ``options`` in a child process; ``progress`` receives the child's progress events in this process.

    Raises :class:`SeesysError` with the child's message on bad input, or :class:`WorkerCrash` when the child
    died without reporting (ORB-SLAM3 exit or segfault) or reported nothing for ``[supervisor] stall_timeout_s``
    (a hang: the child is killed); the session folder keeps what was logged.
    """
    stall_timeout_s = load_slam_config(options.config_dir).supervisor.stall_timeout_s
    context = multiprocessing.get_context("spawn")
    events: multiprocessing.Queue = context.Queue()
    child = context.Process(target=worker_main, args=(options, events, os.getpid()), name="seesys-device-worker")
    child.start()
    outcome: _Failed | _Finished | None = None
    stalled = False
    last_event = time.monotonic()
    try:
        while outcome is None:
            alive = child.is_alive()  # checked before the read, so a last message sent before exiting is not missed
            try:
                event = events.get(timeout=POLL_S)
            except queue.Empty:
                if not alive:
                    break
                if time.monotonic() - last_event > stall_timeout_s:
                    stalled = True
                    child.kill()  # a hung ORB-SLAM3 thread does not answer SIGTERM
                    break
                continue
            last_event = time.monotonic()
            if isinstance(event, (_Failed, _Finished)):
                outcome = event
            elif progress:
                progress(event)
        child.join()
    except KeyboardInterrupt:
        # A SIGINT sent to this process alone (a supervisor such as `seesys run` stopping it) does not reach the
        # child: pass it on, and the child records the interruption and closes its files.
        if child.is_alive() and child.pid is not None:  # alive: started, so it has a pid
            os.kill(child.pid, signal.SIGINT)
        child.join()
        raise
    finally:
        events.close()
    if isinstance(outcome, _Finished):
        return outcome.result
    if isinstance(outcome, _Failed):
        raise SeesysError(outcome.message)
    # The frame being processed when the process died is the first one not in frames.csv.
    next_frame = frames_logged(options.out_dir)
    if stalled:
        message = _ending_message(
            f"stopped responding (no frame for {stall_timeout_s:g} s; killed)", next_frame, options.out_dir
        )
    else:
        message = _crash_message(child.exitcode, next_frame, options.out_dir)
    if (options.out_dir / session_layout.MANIFEST).exists():
        session_files.update_manifest(
            options.out_dir, status="crashed", end_time=session_files.utc_now(), error=message, frames=next_frame
        )
    raise WorkerCrash(message)
