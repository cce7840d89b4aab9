"""SEESys: online pose error estimation for visual SLAM.

This package is the bottom of SEESys's layers (docs/architecture.md), what a user imports: :mod:`seesys.core` holds
the concepts every part shares, as pure code, :mod:`seesys.io` the thin I/O on top of it, and :mod:`seesys.client`
the estimates for applications. The app and the ``seesys`` command line that compose the parts are
:mod:`seesys_app`; ``python -m seesys`` runs that command line.
"""

__version__ = "0.1.0"
