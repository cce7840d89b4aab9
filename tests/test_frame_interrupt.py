"""A SIGINT that reaches the device while it logs a frame and hands it to its observers is held until both are
done: ``frames.csv`` and the monitor's logs never differ by the interrupted frame (the device's Ctrl-C test saw
``frames.csv`` one frame ahead of ``monitor_stats.json`` once)."""

from __future__ import annotations

import os
import signal

import pytest

from slam_monitor.device_worker import holding_interrupt


def test_an_interrupt_inside_the_block_is_raised_at_its_end_and_the_handler_is_restored():
    done = []
    # Python's own SIGINT handler, as a device process has it (another test may have left one of its own here)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt), holding_interrupt():
            os.kill(os.getpid(), signal.SIGINT)  # delivered to this, the main, thread before kill returns
            done.append("logged")
            done.append("handed to the observers")
        assert done == ["logged", "handed to the observers"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_the_devices_own_handler_is_the_one_called_and_a_block_without_a_signal_raises_nothing():
    calls = []

    def handler(signum, frame):
        calls.append(signum)

    before = signal.signal(signal.SIGINT, handler)
    try:
        with holding_interrupt():
            pass
        assert calls == []
        with holding_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            assert calls == []  # held
        assert calls == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, before)
