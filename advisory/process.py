"""The command line of the advisory's processes (generator, player), for its supervisor and the tests."""

from __future__ import annotations

import sys


def advisory_command(*args: str) -> list[str]:
    """The command line of ``seesys advisory ARGS`` with this interpreter."""
    return [sys.executable, "-m", "seesys", "advisory", *args]
