"""The follow-command <-> ``FollowEvent`` codec: one mapping for the node, the bags and replay.

The follow node logs each accepted follow command on ``follow/events`` (:func:`encode`), the
headless bag writer logs a scenario's commands the same way, and replay re-issues a recorded
event as the command it was (:func:`decode`), so a bag replays bit for bit. A command is a name
and the keyword arguments of ``FollowController.command``; an event is ``kind`` and the fields
below (``ladrc_msgs/FollowEvent``).
"""

from __future__ import annotations

import json
import math
from typing import Any, NamedTuple

from .codes import EventKind

WAVE_ARGS = ('kind', 'freq_hz', 'freq_end_hz', 'duration_s')
"""A target wave's arguments besides its amplitude, carried as JSON in ``text``."""


class EventFields(NamedTuple):
    """The fields of one ``FollowEvent`` besides its header and tick."""

    kind: int
    value_mm: float = math.nan
    delay_s: float = 0.0
    velocity_mm_s: float = 0.0
    accel_mm_s2: float = 0.0
    flag: bool = False
    text: str = ''


COMMAND_KIND: dict[str, EventKind] = {
    'start_follow': EventKind.START_FOLLOW,
    'stop_follow': EventKind.STOP_FOLLOW,
    'set_target': EventKind.SET_TARGET,
    'machining': EventKind.MACHINING,
    'height_compensation': EventKind.HEIGHT_COMPENSATION,
    'gradient_follow': EventKind.GRADIENT_FOLLOW,
    'reset_fault': EventKind.RESET_FAULT,
    'target_wave': EventKind.TARGET_WAVE,
    'pierce': EventKind.PIERCE,
    'lift': EventKind.LIFT,
    'hold': EventKind.HOLD,
    'leapfrog': EventKind.LEAPFROG,
}
"""The follow commands a ``FollowEvent`` records (``PARAMETERS`` is a parameter set)."""


def encode(name: str, args: dict[str, Any]) -> EventFields:
    """Return the event of command ``name`` with keyword arguments ``args``."""
    kind = COMMAND_KIND[name]
    a = args
    if name in ('start_follow', 'set_target'):
        return EventFields(kind, float(a['target_gap_mm']))
    if name == 'machining':
        return EventFields(kind, flag=bool(a['on']))
    if name == 'height_compensation':
        return EventFields(kind, float(a['offset_mm']), float(a.get('delay_s', 0.0)))
    if name == 'gradient_follow':
        return EventFields(kind, float(a['target_gap_mm']), float(a.get('delay_s', 0.0)),
                           float(a.get('velocity_mm_s', 0.0)), float(a.get('accel_mm_s2', 0.0)))
    if name == 'target_wave':
        return EventFields(kind, float(a['amp_mm']),
                           text=json.dumps({k: a[k] for k in WAVE_ARGS}))
    if name == 'pierce':
        return EventFields(kind, float(a['cut_gap_mm']), text=json.dumps(
            {'heights_mm': list(a['heights_mm']), 'dwell_s': list(a['dwell_s']),
             'thc_delay_s': a['thc_delay_s'], **({'locked': True} if a.get('locked') else {})}))
    if name == 'lift':
        return EventFields(kind, float(a['value_mm']), velocity_mm_s=float(a['velocity_mm_s']),
                           flag=bool(a['mode']))
    if name == 'leapfrog':
        return EventFields(kind, float(a['arrive_height_mm']), text=json.dumps(
            {k: a[k] for k in ('lift_mm', 'rapid_length_mm', 'rapid_feed_mm_s')}))
    if name == 'hold':
        return EventFields(kind, delay_s=-1.0 if a['at_next_segment'] else 0.0,
                           flag=bool(a['hold']), text=a['reason'])
    return EventFields(kind)  # stop_follow, reset_fault


def decode(ev: Any) -> tuple[str, dict[str, Any]]:
    """Return ``(command name, kwargs)`` that re-issue event ``ev`` exactly as it ran.

    ``ev`` has the fields of :class:`EventFields` (a recorded ``FollowEvent``). Raises
    ``ValueError`` for a kind that is not a follow command.
    """
    k = ev.kind
    if k in (EventKind.START_FOLLOW, EventKind.SET_TARGET):
        name = 'start_follow' if k == EventKind.START_FOLLOW else 'set_target'
        return name, {'target_gap_mm': ev.value_mm}
    if k == EventKind.MACHINING:
        return 'machining', {'on': ev.flag}
    if k == EventKind.HEIGHT_COMPENSATION:
        return 'height_compensation', {'offset_mm': ev.value_mm, 'delay_s': ev.delay_s}
    if k == EventKind.GRADIENT_FOLLOW:
        return 'gradient_follow', {'target_gap_mm': ev.value_mm, 'delay_s': ev.delay_s,
                                   'velocity_mm_s': ev.velocity_mm_s,
                                   'accel_mm_s2': ev.accel_mm_s2}
    if k == EventKind.TARGET_WAVE:
        return 'target_wave', {'amp_mm': ev.value_mm, **json.loads(ev.text)}
    if k == EventKind.PIERCE:
        d = json.loads(ev.text)
        return 'pierce', {'heights_mm': tuple(d['heights_mm']), 'dwell_s': tuple(d['dwell_s']),
                          'cut_gap_mm': ev.value_mm, 'thc_delay_s': d['thc_delay_s'],
                          'locked': bool(d.get('locked', False))}  # (older bags: unlocked)
    if k == EventKind.LIFT:
        return 'lift', {'mode': int(ev.flag), 'value_mm': ev.value_mm,
                        'velocity_mm_s': ev.velocity_mm_s}
    if k == EventKind.LEAPFROG:
        return 'leapfrog', {**json.loads(ev.text), 'arrive_height_mm': ev.value_mm}
    if k == EventKind.HOLD:
        return 'hold', {'hold': ev.flag, 'at_next_segment': ev.delay_s < 0.0, 'reason': ev.text}
    if k in (EventKind.STOP_FOLLOW, EventKind.RESET_FAULT):
        return ('stop_follow' if k == EventKind.STOP_FOLLOW else 'reset_fault'), {}
    raise ValueError(f'follow/events kind {k} is not a follow command')
