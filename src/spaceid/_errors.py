"""The one exception type that the command line turns into a one-line message."""

__all__ = ["SpaceidError"]


class SpaceidError(ValueError):
    """Bad input or an ill-posed problem, with a message that says what to fix.

    Library code raises it; only the CLI turns it into ``error: <message>`` and exit code 2.
    The message names the file or field, what was expected, what arrived and how to fix it.
    """
