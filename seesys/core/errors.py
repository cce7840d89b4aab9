"""The one exception type a user sees as a one-line message instead of a traceback."""


class SeesysError(Exception):
    """A problem with the user's input or environment, stated so that the user can fix it.

    The ``seesys`` command prints ``seesys: error: <message>`` and exits with status 2; anything that is not a
    ``SeesysError`` is a bug in SEESys and keeps its traceback.
    """


class ConfigError(SeesysError):
    """A configuration file is missing, malformed, or has an unknown or missing key."""
