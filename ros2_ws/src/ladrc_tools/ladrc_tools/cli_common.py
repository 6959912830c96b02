"""What every ``ladrc`` subcommand shares: its entry, its one-line error, the exit code.

A package above ladrc_tools adds subcommands without being imported here: it names a
:class:`Command` in its setup.py under the entry-point group :data:`COMMAND_GROUP`
(``'ladrc.commands': ['fleet = ladrc_fleet.cli:FLEET']``), as ROS 2's ``ros2`` command finds
its verbs (``ros2cli.command``).
"""

from __future__ import annotations

import argparse
from typing import Callable, NamedTuple

EXIT_USAGE = 2
COMMAND_GROUP = 'ladrc.commands'
"""The entry-point group of the subcommands other packages add to ``ladrc``."""


class Command(NamedTuple):
    """One ``ladrc`` subcommand: its help line, its arguments, its run (returns the exit code)."""

    help: str
    add: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""
