"""The one-commander lock lives in the contract (``ladrc_contract.commander_lock``).

A real driver needs it too, and machine-side packages never import the simulator; this module
keeps the old import path working.
"""

from ladrc_contract.commander_lock import CommanderLock, Identity, describe

__all__ = ['CommanderLock', 'Identity', 'describe']
