"""Exceptions raised for bad user input."""


class ConfigError(ValueError):
    """Invalid user input (a parameter, a name, a path). The message names the culprit.

    The CLI turns it into a one-line message and exit code 2.
    """
