"""Fixtures every test can ask for by name: the embedded sample and a small writable copy of it, and those of the
advisory, service, Ray and estimator tests (defined in ``testkit``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from testkit.audio import jack, make_sandbox
from testkit.deepsee import single_thread, tiny_dataset, trained_runs
from testkit.ray_cluster import local_ray
from testkit.sample import SAMPLE, copy_tum_subset
from testkit.service import setup_factory, tiny_head_model, tiny_model


@pytest.fixture(scope="session")
def sample_dir() -> Path:
    return SAMPLE


@pytest.fixture
def small_tum(tmp_path) -> Path:
    """The first 12 sample frames as a writable TUM folder (tests may damage it)."""
    return copy_tum_subset(SAMPLE, tmp_path / "tum", 12)
