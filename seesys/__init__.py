"""SEESys: online pose error estimation for visual SLAM.

This package is the bottom and the top of SEESys's layers (docs/architecture.md): :mod:`seesys.core` holds the
concepts every part shares, as pure code, and :mod:`seesys.io` the thin I/O on top of it; :mod:`seesys.app` (the
``seesys run`` app) and :mod:`seesys.cli` (the ``seesys`` command line that gathers each part's subcommands)
compose the parts.
"""

__version__ = "0.1.0"
