"""A node's last step: SIGINT and SIGTERM ignored while the interpreter exits.

A node installs its own SIGINT/SIGTERM handlers (stop the loop, zero command, summary). Once its
``main`` has shut rclpy down, Python's finalization puts the default action back for every
signal with a Python handler; a stop signal in that window (the bring-up stopping every node at
the end of a run, while this one is already exiting by itself) then ends the process as killed
(exit -2) after it has done everything right. An ignored signal stays ignored through
finalization (CPython's ``_PySignal_Fini`` leaves ``SIG_IGN`` alone).
"""

from __future__ import annotations

import signal


def ignore_stop_signals() -> None:
    """Ignore SIGINT and SIGTERM from here to the process's end (call it last in ``main``)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):  # not the main thread, or an exotic platform
            pass
