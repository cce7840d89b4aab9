"""Where SEESys finds the files it ships: ``configs/`` (every default) and ``data/`` (the ORB vocabulary, the
embedded sample, real trajectories for the renderer, trained models).

The SEESys home is the first of:

1. ``$SEESYS_HOME``, a folder holding ``configs/`` and ``data/`` (for a lab's own copy of the defaults);
2. the source checkout the code runs from (an editable install, or ``python -m seesys`` in the repository);
3. ``<prefix>/share/seesys``, where ``pip install`` puts both folders from the wheel (``prefix`` being the
   virtual environment, the system or the user scheme, whichever the package was installed into).

``$SEESYS_CONFIG_DIR`` still overrides the configuration folder alone (:func:`seesys.io.config.config_dir`).
"""

from __future__ import annotations

import os
import sysconfig
from pathlib import Path

from seesys.core.errors import SeesysError

HOME_ENV = "SEESYS_HOME"
SHARE_SUBDIR = Path("share") / "seesys"


class ResourceError(SeesysError):
    """The SEESys home (configs/ and data/) cannot be found."""


def _is_home(folder: Path) -> bool:
    return (folder / "configs").is_dir()


def _installed_homes() -> list[Path]:
    schemes = [sysconfig.get_default_scheme(), sysconfig.get_preferred_scheme("user")]
    return [Path(sysconfig.get_path("data", scheme)) / SHARE_SUBDIR for scheme in dict.fromkeys(schemes)]


def home() -> Path:
    """The folder holding ``configs/`` and ``data/``; raises :class:`ResourceError` naming where it looked."""
    env = os.environ.get(HOME_ENV)
    if env:
        folder = Path(env).expanduser()
        if not _is_home(folder):
            raise ResourceError(f"${HOME_ENV} is {folder}, which has no configs/ folder")
        return folder
    candidates = [Path(__file__).resolve().parents[2], *_installed_homes()]
    for folder in candidates:
        if _is_home(folder):
            return folder
    raise ResourceError(
        "cannot find the SEESys configs/ folder; looked in "
        + ", ".join(map(str, candidates))
        + f" (set ${HOME_ENV} to a folder holding configs/ and data/)"
    )


def resolve(path: str | Path) -> Path:
    """``path`` as given when absolute, else relative to the SEESys home (how configs name shipped files)."""
    path = Path(path).expanduser()
    return path if path.is_absolute() else home() / path
