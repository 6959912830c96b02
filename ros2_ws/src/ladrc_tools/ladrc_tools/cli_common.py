"""What every ``ladrc`` subcommand shares: its one-line error and the exit code of bad input."""

from __future__ import annotations

EXIT_USAGE = 2


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""
