"""One exception base for the project, and the bad-input error the CLI turns into exit status 2."""

__all__ = ["OmnirotorError", "InputError"]


class OmnirotorError(Exception):
    """Base class of every error raised on purpose by omnirotor."""


class InputError(OmnirotorError, ValueError):
    """Bad user input: a file, a parameter or an option. The CLI prints it on one line and exits 2."""
