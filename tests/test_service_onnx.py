"""The ONNX serving path: loading a served model imports no PyTorch, the execution providers follow the
``providers`` setting and what ONNX Runtime offers, a running service says which provider runs its workers, and a
worker's batch is the freshest windows that can all finish in time."""

from __future__ import annotations

import json
import subprocess
import sys

import onnxruntime as ort
import pytest
from testkit.service import ServiceProcess, ServiceSetup

from estimator.artefact.onnx_model import CPU, CUDA, choose_providers
from estimator.service.status import format_status
from estimator.service.worker_core import batch_size
from seesys.core.errors import ConfigError

_LOAD_WITHOUT_TORCH = """
import json, sys
from pathlib import Path
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.predictors import load_predictor
from estimator.artefact.transforms import LabelTransform
from estimator.service.model import ServedModel
from estimator.service.worker import Worker
from seesys.io.core_settings import load_window_config
path = Path(sys.argv[1])
served = ServedModel.load(path, load_window_config())
predictor = load_predictor(path, LabelTransform(load_estimator_config().label_transform.k), 8)
print(json.dumps({"torch": "torch" in sys.modules, "onnx": "onnx" in sys.modules, "provider": served.provider,
                  "kind": predictor.kind}))
"""


@pytest.mark.system
def test_loading_the_onnx_model_imports_no_torch(tiny_model):
    """A worker's start-up (the worker module, the served model, the ONNX predictor) never imports PyTorch."""
    result = subprocess.run(
        [sys.executable, "-c", _LOAD_WITHOUT_TORCH, str(tiny_model)], capture_output=True, text=True, check=True
    )
    loaded = json.loads(result.stdout)
    assert loaded == {"torch": False, "onnx": False, "provider": choose_providers("auto")[0], "kind": "onnx"}


def test_providers_put_cuda_first_only_where_onnx_runtime_offers_it():
    assert choose_providers("auto", [CUDA, CPU]) == [CUDA, CPU]
    assert choose_providers("auto", ["AzureExecutionProvider", CPU]) == [CPU]
    assert choose_providers("cpu", [CUDA, CPU]) == [CPU]
    assert choose_providers("cuda", [CUDA, CPU]) == [CUDA, CPU]
    with pytest.raises(ConfigError, match="offers only"):
        choose_providers("cuda", [CPU])
    with pytest.raises(ConfigError, match="providers must be one of"):
        choose_providers("gpu", [CPU])


@pytest.mark.system
def test_status_and_worker_log_name_the_provider(tiny_model):
    expected = CUDA if CUDA in ort.get_available_providers() else CPU
    setup = ServiceSetup()
    service = ServiceProcess(setup, tiny_model)
    try:
        status = service.wait_ready()
        assert [w["provider"] for w in status["workers"]] == [expected]
        assert expected.removesuffix("ExecutionProvider") in format_status(status)
        assert f"on {expected}" in service.output()
        assert service.stop() == 0
    finally:
        service.kill()
        setup.cleanup()


@pytest.mark.system
def test_a_provider_setting_that_cannot_be_met_stops_serve_with_one_message(tiny_model):
    setup = ServiceSetup(providers="cuda" if CUDA not in ort.get_available_providers() else "tpu")
    service = ServiceProcess(setup, tiny_model)
    try:
        assert service.process.wait(120) == 2
        assert "seesys: error: providers" in service.output()
    finally:
        service.kill()
        setup.cleanup()


def test_a_batch_is_the_freshest_windows_that_can_all_finish_in_time():
    """At 5 ms a window and a 150 ms limit: the freshest windows go first, and a batch stops before the window that
    could no longer finish in time; no cost measured yet, and max_batch decides; at least one window always runs."""
    assert batch_size([0.0] * 3, max_batch=16, window_ms=5.0, stale_after_ms=150.0) == 3
    assert batch_size([1.0] * 30, max_batch=16, window_ms=1.0, stale_after_ms=150.0) == 16
    assert batch_size([100.0] * 16, max_batch=16, window_ms=5.0, stale_after_ms=150.0) == 10
    assert batch_size([100.0] * 16, max_batch=16, window_ms=0.0, stale_after_ms=150.0) == 16
    # 10, 20, ..., 140 ms old: in a batch of 10 the tenth (100 ms old) finishes at 150 ms, in one of 11 the
    # eleventh (110 ms) at 165
    ages = [10.0 * k for k in range(1, 15)]
    assert batch_size(ages, max_batch=16, window_ms=5.0, stale_after_ms=150.0) == 10
    assert batch_size([149.0] * 8, max_batch=16, window_ms=5.0, stale_after_ms=150.0) == 1
