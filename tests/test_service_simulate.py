"""The simulated devices' send schedule (estimator/service/simulate.py)."""

import numpy as np

from estimator.service.simulate import send_schedule
from seesys.io.core_settings import load_window_config

RATE_HZ = 30.0


def _window_end_times(devices: int, spread_s: float) -> np.ndarray:
    windows = load_window_config()
    return np.array(
        sorted(
            due
            for due, _, k in send_schedule(devices, 300, RATE_HZ, spread_s)
            if k >= windows.history and windows.is_psd_frame(k)
        )
    )


def test_every_device_sends_every_frame_at_the_camera_rate_in_time_order():
    schedule = send_schedule(4, 90, RATE_HZ, 0.1)
    assert [due for due, _, _ in schedule] == sorted(due for due, _, _ in schedule)
    for device in range(4):
        dues = [due for due, j, _ in schedule if j == device]
        frames = [k for _, j, k in schedule if j == device]
        assert frames == list(range(90))
        np.testing.assert_allclose(np.diff(dues), 1 / RATE_HZ)
        assert dues[0] == device * 0.1 / 4


def test_spread_phases_pace_the_window_ends_and_bunched_ones_burst():
    period = load_window_config().end_stride / RATE_HZ
    spread = np.diff(_window_end_times(16, period))
    np.testing.assert_allclose(spread, period / 16, atol=1e-9)  # one window end every 1/16 estimate period
    bunched = np.diff(_window_end_times(16, 1 / RATE_HZ))
    assert bunched.max() > period / 2 and np.median(bunched) < 1 / (16 * RATE_HZ) + 1e-9  # bursts, then silence
