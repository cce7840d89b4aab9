"""SEESys: online pose error estimation for visual SLAM.

This package holds what the parts share: the configuration loader, the error type every command reports as
one line, and the ``seesys`` command line that gathers each part's subcommands.
"""

__version__ = "0.1.0"
