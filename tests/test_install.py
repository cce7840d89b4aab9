"""SEESys installed from its wheel into a fresh virtual environment outside the checkout.

The dependencies are the pinned ones this test suite runs with: the new environment sees the project
environment's site-packages as a plain path entry, so no package is downloaded, while the project's own editable
install (a ``.pth`` hook there, which a plain path entry does not run) stays invisible. ``seesys`` must then come
from the wheel, and find its configs, vocabulary and sample where the wheel put them.
"""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    root = tmp_path_factory.mktemp("install")
    # Built from a copy of the files git knows, so that nothing left in the checkout (an old build/) gets in.
    source = root / "source"
    files = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split("\0")
    for name in filter(None, files):
        if (REPO / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, source / name)
    wheels = root / "wheels"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(wheels),
            str(source),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    (wheel,) = wheels.glob("seesys-*.whl")
    env_dir = root / "env"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    Path(purelib, "project_dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
        check=True,
        capture_output=True,
        text=True,
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SEESYS_", "PYORBSLAM3_", "PYTHON"))}
    return env_dir, env


def run(installed, *args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env_dir, env = installed
    return subprocess.run(
        [str(env_dir / "bin" / "seesys"), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )


@pytest.mark.system
def test_the_wheel_installs_code_configs_and_data_outside_the_checkout(installed, tmp_path):
    env_dir, env = installed
    where = subprocess.run(
        [
            str(env_dir / "bin" / "python"),
            "-c",
            "import seesys, seesys.io.resources as r; print(seesys.__file__); print(r.home())",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert Path(where[0]).is_relative_to(env_dir), f"seesys imported from {where[0]}, not the new environment"
    home = Path(where[1])
    assert home == env_dir / "share" / "seesys"
    assert (home / "configs" / "slam.toml").is_file() and (home / "data" / "sample" / "rgb.txt").is_file()
    help_ = run(installed, "--help", cwd=tmp_path)
    assert help_.returncode == 0 and "advisory" in help_.stdout


@pytest.mark.slam
@pytest.mark.system
def test_the_installed_command_tracks_its_embedded_sample(installed, tmp_path):
    env_dir, _ = installed
    sample = env_dir / "share" / "seesys" / "data" / "sample"
    out = run(
        installed, "track", "--source", f"tum:{sample}", "--mode", "rgbd", "--out", str(tmp_path / "s"), cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert "frames:  150" in out.stdout and "tracked: 150" in out.stdout
    manifest = json.loads((tmp_path / "s" / "session.json").read_text())
    assert Path(manifest["vocabulary"]).is_relative_to(env_dir / "share" / "seesys" / "data" / "vocabulary")


@pytest.mark.system
def test_a_home_without_configs_is_a_clear_error(installed, tmp_path):
    env_dir, env = installed
    result = subprocess.run(
        [str(env_dir / "bin" / "seesys"), "advisory", "pulses", "0.008"],
        cwd=tmp_path,
        env={**env, "SEESYS_HOME": str(tmp_path)},
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"seesys: error: $SEESYS_HOME is {tmp_path}, which has no configs/ folder"
