"""Children die with their parent, and signals stop a process's loop: ``seesys.io.processes``."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading

import psutil

from seesys.io.processes import dying_with_parent, stop_on_signals

# A parent with busy threads (as a supervisor has: watchers, a status view) starts a sleeping child through the
# launcher, prints the child's pid and waits, without end, to be killed.
PARENT = """
import subprocess, sys, threading, time
from seesys.io.processes import dying_with_parent
def busy():  # threads starting and ending all the time: load, not a wait for anything
    while True:
        threading.Thread(target=time.sleep, args=(0.001,)).start()
        time.sleep(0.001)
for _ in range(2):
    threading.Thread(target=busy, daemon=True).start()
child = subprocess.Popen(dying_with_parent([sys.executable, "-c", "import signal; signal.pause()"]))
print(child.pid, flush=True)
threading.Event().wait()  # until killed
"""

# Ends its loop on SIGTERM while it waits on the event and starts threads, the two places where a handler that set
# the event or started a thread itself could deadlock.
LOOP = """
import threading
from seesys.io.processes import stop_on_signals
with stop_on_signals() as stop:
    print("ready", flush=True)
    while not stop.wait(0.0001):
        threading.Thread(target=lambda: None).start()
print("stopped", flush=True)
"""


def test_a_child_started_through_the_launcher_gets_sigterm_when_its_parent_is_killed():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    child = psutil.Process(int(parent.stdout.readline()))
    assert child.ppid() == parent.pid  # the launcher exec'd the program in its place
    parent.kill()
    parent.communicate(timeout=60)
    gone, alive = psutil.wait_procs([child], timeout=60)
    assert not alive, f"the child outlived its killed parent: {child.cmdline()}"
    assert gone[0].returncode in (None, -signal.SIGTERM)  # None: reaped by init, not by us


def test_a_program_that_cannot_run_ends_the_launcher_with_127_and_says_why():
    done = subprocess.run(dying_with_parent(["no-such-program-here"]), capture_output=True, text=True, timeout=60)
    assert done.returncode == 127
    assert "cannot run no-such-program-here" in done.stderr


def test_sigterm_ends_a_loop_that_waits_and_starts_threads():
    for _ in range(5):
        loop = subprocess.Popen([sys.executable, "-c", LOOP], stdout=subprocess.PIPE, text=True)
        assert loop.stdout.readline().strip() == "ready"
        loop.send_signal(signal.SIGTERM)
        out, _ = loop.communicate(timeout=60)
        assert loop.returncode == 0 and out.strip() == "stopped"


def test_the_handlers_come_back_after_the_block_and_its_thread_ends():
    before = signal.getsignal(signal.SIGTERM)
    threads = threading.active_count()
    with stop_on_signals() as stop:
        signal.raise_signal(signal.SIGTERM)
        assert stop.wait(60)
    assert signal.getsignal(signal.SIGTERM) is before
    assert threading.active_count() == threads
