"""A real device (ORB-SLAM3 on the sample, the RTS monitor streaming, the estimate observer logging) and the
estimator service killed with SIGKILL mid-stream, then restarted: the device never notices beyond a gap in its
estimates."""

from __future__ import annotations

import shutil
import threading
import time

import pandas as pd
import psutil
import pytest
from testkit.polling import wait_for
from testkit.sample import SAMPLE
from testkit.service import ServiceProcess, ServiceSetup

from seesys.core import session_layout
from seesys.core.session_layout import ESTIMATES_CSV
from seesys.io.core_settings import load_window_config
from seesys.io.rts_log import read_rts_csv
from slam_monitor.device_worker import ObserverSpec, SessionOptions
from slam_monitor.monitor_commands import ESTIMATES_FACTORY, MONITOR_FACTORY
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.supervisor import run_supervised_session

pytestmark = pytest.mark.slam
# Back and forth over the sample: continuous motion for ORB-SLAM3, long enough (20 s at 30 Hz; a device on a
# loaded machine runs slower still) to outlast a restart of the service.
LEGS = 4


def back_and_forth(folder):
    """A TUM folder playing the sample forwards, backwards, forwards... with timestamps going on at 30 Hz."""
    folder.mkdir()
    shutil.copyfile(SAMPLE / "calibration.yaml", folder / "calibration.yaml")
    rgb = [line.split() for line in (SAMPLE / "rgb.txt").read_text().splitlines() if not line.startswith("#")]
    depth = [line.split() for line in (SAMPLE / "depth.txt").read_text().splitlines() if not line.startswith("#")]
    order = []
    for leg in range(LEGS):
        indices = range(len(rgb)) if leg % 2 == 0 else range(len(rgb) - 2, 0, -1)
        order += list(indices)
    for name, rows in (("rgb.txt", rgb), ("depth.txt", depth)):
        (folder / name).write_text("".join(f"{k / 30:.6f} {SAMPLE / rows[i][1]}\n" for k, i in enumerate(order)))
    return len(order)


def rows(out):
    path = out / ESTIMATES_CSV
    return pd.read_csv(path) if path.exists() else pd.DataFrame()


@pytest.mark.system
def test_sigkill_of_the_service_mid_stream_then_restart(tmp_path, tiny_model, record_property):
    setup = ServiceSetup(connect_device_stream=True)
    frames = back_and_forth(tmp_path / "source")
    out = tmp_path / "session"
    # at camera rate as a live camera, never waiting for ORB-SLAM3's mapping (which made this run last minutes)
    options = SessionOptions(
        source=f"tum:{tmp_path / 'source'}",
        mode=SlamMode.RGBD,
        out_dir=out,
        pace=True,
        wait_for_mapping=False,
        config_dir=setup.config_dir,
        observers=(ObserverSpec(MONITOR_FACTORY, {"stream": True}), ObserverSpec(ESTIMATES_FACTORY)),
    )
    service = ServiceProcess(setup, tiny_model)
    restarted = None
    outcome: dict = {}

    def device():
        try:
            outcome["result"] = run_supervised_session(options)
        except BaseException as e:  # reported by the assertion below
            outcome["error"] = e

    thread = threading.Thread(target=device)
    try:
        workers = [w["pid"] for w in service.wait_ready()["workers"]]
        thread.start()
        wait_for(lambda: len(rows(out)) >= 3 or not thread.is_alive(), 300, "the first estimates on the device")
        assert thread.is_alive(), f"the session ended before the estimates came: {outcome}"
        service.kill()  # SIGKILL: no clean-up of any kind
        killed_at = time.time()
        before = len(rows(out))
        gone, alive = psutil.wait_procs([psutil.Process(p) for p in workers if psutil.pid_exists(p)], timeout=30)
        assert not alive, "a worker outlived its service"

        restarted = ServiceProcess(setup, tiny_model)
        restarted.wait_ready()
        ready_at = time.time()
        wait_for(
            lambda: (rows(out).received_unix > ready_at).any() or not thread.is_alive(),
            300,
            "estimates after the restart",
        )
        thread.join()
    finally:
        for s in (service, restarted):
            if s is not None:
                s.kill()
        thread.join()
        setup.cleanup()

    assert "error" not in outcome, outcome.get("error")
    result = outcome["result"]
    assert result.frames == frames  # the device tracked to the end of its source
    assert list(pd.read_csv(out / session_layout.FRAMES_CSV).frame_index) == list(range(frames))
    assert list(read_rts_csv(out).frame_index) == list(range(frames))
    log = rows(out)
    after = log[log.received_unix > ready_at]
    assert len(after) > 0, "no estimate after the restart"
    resumed_s = float(after.received_unix.min() - ready_at)
    record_property("estimates_resumed_after_restart_s", resumed_s)
    record_property("estimate_gap_s", float(after.received_unix.min() - killed_at))
    print(
        f"estimates: {before} before the kill, {len(after)} after the restart; first {resumed_s:.3f} s after the "
        f"restarted service was ready, {after.received_unix.min() - killed_at:.1f} s after the kill"
    )
    assert log.frame_index.is_monotonic_increasing
    assert (log.frame_index % load_window_config().end_stride == 0).all()
    assert log.end_to_end_ms.notna().sum() > 0 and (log.error_m >= 0).all()
    timed = log.dropna(subset=["preprocess_ms", "transmit_inference_ms", "end_to_end_ms"])
    assert len(timed) > 0 and (timed[["preprocess_ms", "transmit_inference_ms"]] >= 0).all().all()
    assert (abs(timed.preprocess_ms + timed.transmit_inference_ms - timed.end_to_end_ms) < 0.01).all()
    assert (abs(log.tracking_ms + log.end_to_end_ms - log.capture_to_estimate_ms) < 0.01).all()
