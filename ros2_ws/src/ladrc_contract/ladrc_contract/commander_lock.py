"""One commander: the drive executes the velocity commands of exactly one commander.

The drive side of the contract (docs/interfaces.md, "One commander"); plain Python, no rclpy,
so a driver for a real axis carries the same class (docs/real-axis.md). A commander is the pair
``(commander, session)`` of :class:`VelocityCommand`: the fully qualified node name and a random
number its process draws at start. The pair is in the message, not taken from the middleware:
Jazzy's rclpy gives a subscriber no publisher identity per message (only sequence numbers), and
the graph (who publishes) is known only after discovery, so it cannot judge the message that
arrives now. Two processes with one node name (a second controller started by mistake) differ in
``session``; a ``ros2 topic pub`` or a tool that leaves the fields empty is nobody's.

Rules (the drive cycle that receives a message applies them, before the command is used):

* no commander yet: the first message with a name and a session != 0 makes its sender the
  commander; a message without them is foreign;
* the commander's messages are executed; its ``release`` message (its last: zero velocity,
  enable false) is executed and ends its command, so another may take the axis: a handover;
* any other message is **foreign**: it is not executed, and from it on the drive brakes (quick
  stop) and reports a fault naming both senders, until :meth:`reset` (the driver's reset
  service); no message is executed while faulted, not even the commander's.

This is a guard against mistakes, not security: a sender that copies another's identity is not
detected (SROS2 is where who may publish is enforced; docs/safety.md).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

Identity = tuple[str, int]  # (commander, session)


def describe(identity: Identity) -> str:
    """``'/ladrc_follow' (session 123)``, or the empty identity as such."""
    name, session = identity
    return f'{name or "<no commander>"!r} (session {session})'


@dataclass
class CommanderLock:
    """Who may command the drive; :meth:`admit` each command as it arrives."""

    owner: Identity | None = None
    fault_reason: str = ''
    executed: Counter = field(default_factory=Counter)  # admitted commands per identity
    refused: Counter = field(default_factory=Counter)  # foreign commands per identity

    def admit(self, commander: str, session: int, release: bool) -> bool:
        """Return True if this command is to be executed (see the module docstring)."""
        identity = (str(commander), int(session))
        if self.fault_reason:
            if identity == self.owner:
                return False  # faulted: nothing executes until the reset
            self.refused[identity] += 1
            return False
        if self.owner is None:
            if not identity[0] or identity[1] == 0:
                return self._foreign(identity)
            self.owner = identity
        elif identity != self.owner:
            return self._foreign(identity)
        self.executed[identity] += 1
        if release:
            self.owner = None  # handover: the next commander may take the axis
        return True

    def _foreign(self, identity: Identity) -> bool:
        self.refused[identity] += 1
        owner = describe(self.owner) if self.owner is not None else 'no commander'
        self.fault_reason = (f'second commander: a velocity command from {describe(identity)} '
                             f'while {owner} commands the axis; not executed, quick stop '
                             'until the drive is reset')
        return False

    def reset(self) -> str:
        """Clear the fault and the commander (the next one takes the axis); return what was."""
        was = self.fault_reason
        self.fault_reason = ''
        self.owner = None
        return was

    def summary(self) -> dict[str, dict[str, int]]:
        """Commands executed and refused per sender (the drive's log of its commands' source)."""
        return {'executed': {describe(k): v for k, v in self.executed.items()},
                'refused': {describe(k): v for k, v in self.refused.items()}}
