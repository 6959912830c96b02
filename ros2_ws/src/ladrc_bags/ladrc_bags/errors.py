"""The bag tools' one error: what cannot be written or read, in one line."""

from __future__ import annotations


class BagError(Exception):
    """A bag cannot be written or read; the message is one line saying what and why."""
