"""Errors that reach the user as one clear line (the CLI prints them, exit code 2)."""


class DsteleopError(Exception):
    """Bad input or environment: the message is shown to the user as is, without a traceback."""
