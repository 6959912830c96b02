"""A node's last step (kept for the callers not yet on :mod:`ladrc_contract.node_entry`)."""

from __future__ import annotations

from .node_entry import ignore_stop_signals

__all__ = ['ignore_stop_signals']
