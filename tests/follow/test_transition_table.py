"""The follow state machine's transition table: the docs' diagram and ``enter`` follow it."""

from __future__ import annotations

import math
from pathlib import Path
import re

from ladrc_follow.control.follow import FollowController, FollowState, TickInput
from ladrc_follow.control.follow.states import TRANSITIONS, diagram
import pytest

DOC = Path(__file__).resolve().parents[2] / 'docs' / 'follow-state-machine.md'


def test_the_docs_diagram_is_the_table():
    text = DOC.read_text()
    m = re.search(r'<!-- transitions:begin -->\n```mermaid\n(.*?)```\n<!-- transitions:end -->',
                  text, re.S)
    assert m, 'docs/follow-state-machine.md has no generated transition diagram'
    assert m.group(1) == diagram(), 'stale diagram: regenerate it from states.diagram()'


def test_enter_refuses_a_pair_outside_the_table_and_the_tick_ends_in_a_zero_command():
    c = FollowController()
    assert (FollowState.IDLE, FollowState.LADRC) not in TRANSITIONS
    with pytest.raises(RuntimeError, match='IDLE -> LADRC is not in the transition table'):
        c.enter(FollowState.LADRC)
    assert c.state == FollowState.IDLE
    # every state may enter FAULT, so the exception path (fail) can never raise itself
    assert all((s, FollowState.FAULT) in TRANSITIONS for s in FollowState)


def test_a_follow_passes_only_table_transitions():
    c = FollowController()
    seen = []
    enter = c.enter

    def spy(state):
        seen.append((int(c.state), int(state)))
        enter(state)

    c.enter = spy
    c.command('start_follow', target_gap_mm=1.0)
    gap, enc, u = 3.0, 0.0, 0.0
    h = c.params.h_s
    for k in range(6000):  # 3 s: lock, approach, PID, LADRC
        t = k * h
        u = c.step(TickInput(t, gap, True, t, enc, t, True, False))
        enc += u * h
        gap += u * h
        assert math.isfinite(u)
    c.command('stop_follow')
    c.step(TickInput(6000 * h, gap, True, 6000 * h, enc, 6000 * h, True, False))
    assert (FollowState.PID, FollowState.LADRC) in seen and seen[0] == (0, 1), seen
    assert all(pair in TRANSITIONS for pair in seen), seen
    assert c.state == FollowState.IDLE
