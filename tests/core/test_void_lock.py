"""Void lock (control/void_lock.py): one lock: a one-sample jump, a fast fall, counts."""

from __future__ import annotations

from ladrc_contract.codes import FollowState, SubState
from ladrc_follow.control.edge import FALLING, OK, EdgeGuard, EdgeParams
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import params_from_dict
from ladrc_follow.control.void_lock import VoidLock
import pytest

H = 0.0005


def _lock(lock_ticks: int = 1, unlock_ticks: int = 1, fall_mm_s: float = 30.0,
          tau_s: float = 0.0) -> VoidLock:
    v = VoidLock({'jump': 0, 'void_lock': 0})
    v.configure(0.3, 0.01, fall_mm_s, tau_s, lock_ticks, unlock_ticks, H)
    return v


@pytest.mark.parametrize('on, off', [(1, 1), (2, 10), (5, 3)])
def test_slope_locks_after_its_count_and_unlocks_after_its_count(on, off):
    v = _lock(on, off)  # tau 0: the slope as given, so the counts alone decide
    seq = [v.slope(-100.0) for _ in range(on + 3)]
    assert seq == [False] * (on - 1) + [True] * 4
    assert v.counts['void_lock'] == 1 and v.reason.startswith('void lock: the apparent surface')
    seq = [v.slope(0.0) for _ in range(off + 2)]
    assert seq == [True] * (off - 1) + [False] * 3
    # a slope beyond the limit for fewer ticks than the count never locks
    if on > 1:
        assert not any(v.slope(-100.0 if i % on else 0.0) for i in range(4 * on))
    assert v.counts['void_lock'] == 1


def test_a_single_calm_tick_inside_a_fall_does_not_unlock_with_an_unlock_count():
    v = _lock(2, 10)
    for _ in range(3):
        v.slope(-100.0)
    # a fall with calm ticks in between (a ragged hole edge) stays one locked episode
    pattern = [0.0, -100.0, 0.0, 0.0, -100.0, -100.0, 0.0]
    assert all(v.slope(s) for s in pattern)
    assert v.counts['void_lock'] == 1


def test_a_jump_locks_at_once_until_its_level_persists_and_is_one_episode_with_the_fall():
    v = _lock(2, 10)
    assert not v.sample(0.0, 0.1)  # within jump_mm: used
    held = []
    while not held or held[-1]:  # 0.5 mm wider: held until it persisted jump_confirm_s
        held.append(v.sample(len(held) * H + H, 0.5))
    assert len(held) in (21, 22)  # 10 ms at 0.5 ms (the last within a rounding of t)
    assert not v.locked and v.counts['jump'] == len(held) and v.counts['void_lock'] == 1
    assert v.reason.startswith('void lock: reading 0.500 mm wider')
    # the confirmed level's fall, judged by the slope while the jump was held: one episode
    v2 = _lock(1, 1)
    v2.sample(0.0, 0.5)
    v2.slope(-1000.0)
    assert v2.locked and v2.counts['void_lock'] == 1


def test_the_guard_falls_through_its_void_lock_and_a_new_guard_keeps_it():
    """A parameter set while held: the lock's memory is the controller's, not the guard's."""
    v = _lock(1, 20, tau_s=0.004)
    p = EdgeParams(void_unlock_ticks=20)
    g = EdgeGuard(p, H, v)
    z, r, t = 5.0, 1.0, 0.0
    g.update(t, z, r, False, 1.0)
    g._verified(z - r)
    for _ in range(10):
        t += H
        r += 100.0 * H
        g.update(t, z, r, False, 1.0)
    assert v.slope_locked
    g2 = EdgeGuard(p, H, v)
    g2.carry_over(g)
    assert v.slope_locked  # a new guard does not forget the lock
    g2.reset()  # a new follow does
    assert not v.slope_locked and v.surface_mm_s == 0.0


def _run_fall(**edge):
    """Follow at 1 mm; the reading widens at 100 mm/s for 5 ms, then stays: (controller, held)."""
    c = FollowController(params_from_dict({f'edge.{k}': v for k, v in edge.items()}))
    enc = 10.0
    gap = 11.0
    c.command('start_follow', target_gap_mm=1.0)
    t = 0.0
    held = falls = 0
    for k in range(6000):
        t = k * H
        u = c.step((t, gap, True, t, enc, t, True, False, 0))
        enc += u * H
        gap += u * H  # a flat sheet: the reading moves with the axis
        if c.state == FollowState.LADRC and c.followed and k > 3000:
            falls += 1
            if 0 < falls <= 10:
                gap += 100.0 * H  # the sheet falls away under the nozzle (a hole's rim)
            if c.internals()['substate'] == SubState.VOID_LOCK:
                held += 1
                assert u >= 0.0, 'a command toward the sheet while void-locked'
    return c, held


def test_unlock_count_holds_longer_and_the_counts_show_in_the_controller():
    c1, held1 = _run_fall()
    c2, held2 = _run_fall(void_unlock_ticks=40)
    assert c1.counts['void_lock'] >= 1 and c2.counts['void_lock'] >= 1
    assert held2 >= held1 + 30
    assert c2.counts['fall_hold'] > c1.counts['fall_hold']
    assert not c1.fault_reason and not c2.fault_reason


def test_void_lock_counts_are_parameters_of_the_one_schema():
    with pytest.raises(ValueError, match='void_lock_ticks'):
        params_from_dict({'edge.void_lock_ticks': 0})
    p = params_from_dict({'edge.void_lock_ticks': 2, 'edge.void_unlock_ticks': 10})
    assert (p.edge.void_lock_ticks, p.edge.void_unlock_ticks) == (2, 10)
    assert EdgeGuard(EdgeParams(), H).update(0.0, 5.0, 1.0, False, 1.0) == OK
    assert FALLING != OK
