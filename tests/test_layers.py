"""The import contracts of docs/architecture.md (``[tool.importlinter]`` in pyproject.toml): kept on this tree, and
broken, with the offending import named, when a module reaches the wrong way."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("seesys", "seesys_app", "slam_monitor", "synth", "estimator", "advisory", "study", "analysis")
LINT = Path(sys.executable).with_name("lint-imports")


def lint(tree: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` on the packages under ``tree`` (found there first on the path), without a cache."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run(
        [str(LINT), "--config", str(tree / "pyproject.toml"), "--no-cache"],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """A copy of the packages and pyproject.toml, to break on purpose."""
    for name in PACKAGES:
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


@pytest.mark.system
def test_the_contracts_hold_on_this_tree(tree: Path):
    result = lint(tree)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


@pytest.mark.parametrize(
    "module, imported, contract",
    [
        ("estimator/deepsee/metrics.py", "advisory.config", "knows nothing of the advisory"),
        ("estimator/dataset/report.py", "study.sessions", "knows nothing of the advisory or the study"),
        ("slam_monitor/monitor.py", "estimator.diversity", "Layers"),
        ("slam_monitor/monitor.py", "advisory.generator", "know nothing of each other"),
        ("seesys/core/windows.py", "seesys.io.config", "Layers"),
        ("seesys/core/psd.py", "cv2", "The core does no I/O"),
        ("study/metrics.py", "estimator.diversity", "never imports it"),
        ("estimator/dataset/report.py", "study.sessions", "Layers"),
        ("seesys/io/config.py", "seesys_app.records", "import nothing of the app"),
        ("slam_monitor/monitor.py", "seesys_app.records", "import nothing of the app"),
        ("synth/renderer.py", "slam_monitor.image_features", "The renderer (synth) imports no other part"),
        ("synth/renderer.py", "estimator.diversity", "The renderer (synth) imports no other part"),
        ("estimator/service/model.py", "torch", "without PyTorch"),
        ("estimator/artefact/onnx_model.py", "torch", "without PyTorch"),
        ("seesys_app/run.py", "estimator.deepsee.model", "without PyTorch"),
        ("estimator/deepsee/forest_export.py", "estimator.deepsee.baselines", "forest is trained, exported"),
    ],
)
@pytest.mark.system
def test_an_import_the_wrong_way_breaks_a_contract_and_is_named(tree: Path, module: str, imported: str, contract: str):
    path = tree / module
    path.write_text(path.read_text() + f"\nimport {imported}  # noqa: E402,F401\n")
    result = lint(tree)
    assert result.returncode != 0
    assert contract in result.stdout
    assert f"{module.removesuffix('.py').replace('/', '.')} -> {imported}" in result.stdout, result.stdout
