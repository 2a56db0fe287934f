"""The one error family that reaches the user as one clear line (exit code 2, no traceback;
3 for a lost robot).

    DsteleopError        base: the CLI catches it, prints its message and exits 2
      ConfigError        a setting or hyper-parameter out of its domain (the message names it)
      InputError         bad input: a missing, corrupt or unsupported file, a camera that
                         does not open, a malformed session, a port in use
        FormatError      data that breaks its format (a session's record, an operator
                         history, an episode entry); also a ValueError, so a reader that
                         names the file catches it with json's and numpy's parse errors
        ModelFileError   the hand model shipped in the package is missing or not the file
                         its sha256 names (a broken install)
      RobotLostError     the robot stopped answering during a run (its link's far end died):
                         not bad input, so exit code 3, for a script to tell it apart

    ContractError        not a DsteleopError: a function called outside its stated domain
                         (arrays of the wrong shape, too few samples for a test, a mapping
                         not calibrated yet). The caller's bug, so it keeps its traceback.

Anything else that escapes is a bug and keeps its traceback. Validators and input checks raise
one of these, never a bare ValueError (tests/test_errors.py).
"""


class DsteleopError(Exception):
    """Bad input or environment: the message is shown to the user as is, without a traceback."""

    #: The command's exit code when this error ends it.
    exit_code = 2


class ConfigError(DsteleopError, ValueError):
    """A configuration value is out of its domain; the message names the field."""


class InputError(DsteleopError):
    """Input the program cannot use: a file, a camera, a session, an address."""


class FormatError(InputError, ValueError):
    """Data that breaks its format; a ValueError too, so a reader that adds the file and line
    to the message catches it beside the parsers' own errors."""


class ModelFileError(InputError):
    """The model file shipped in the package is missing or does not match its sha256."""


class RobotLostError(DsteleopError):
    """The robot was lost (no state) for longer than allowed during a run: exit code 3."""

    exit_code = 3


class ContractError(ValueError):
    """A function was called outside its stated domain: a bug in the caller, not bad input, so
    the command does not turn it into one line (it keeps its traceback)."""
