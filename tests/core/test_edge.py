"""Edge guard (control/edge.py): feedback gain over travel, fast-fall hold, verification."""

from __future__ import annotations

import math

from ladrc_contract.codes import FollowState, SubState
from ladrc_follow.control import edge
from ladrc_follow.control.edge import (
    EDGE,
    FALLING,
    HOLD,
    OK,
    VERIFY,
    EdgeGuard,
    EdgeParams,
    TravelGain,
)
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict, validate
from ladrc_sim.headless import runner
from ladrc_sim.headless.scenario import load_scenario, scenario_from_dict
import numpy as np
import pytest

H = 0.0005


def _move(tg: TravelGain, speed_mm_s: float, gain: float, ticks: int, z0=5.0, r0=2.0):
    """Feed ``ticks`` of motion at ``speed`` with reading travel = gain x axis travel."""
    out = []
    for i in range(ticks):
        dz = speed_mm_s * H * i
        out.append(tg.update(z0 + dz, r0 + gain * dz))
    return out


@pytest.mark.parametrize('gain', [0.8, 1.0, 1.6])
def test_travel_gain_is_reading_travel_over_axis_travel(gain):
    tg = TravelGain(0.1, 12.0, H)
    k = _move(tg, -20.0, gain, 60)
    assert math.isnan(k[0])
    assert k[-1] == pytest.approx(gain, rel=1e-9)


def test_travel_gain_is_not_judged_on_slow_or_short_travel():
    slow = _move(TravelGain(0.1, 12.0, H), -8.0, 1.6, 400)  # below judge_mm_s
    assert all(math.isnan(k) for k in slow)
    short = TravelGain(0.1, 12.0, H)
    assert all(math.isnan(k) for k in _move(short, -20.0, 1.6, 8))  # 0.07 mm < 0.1 mm


def _guard(**kw) -> EdgeGuard:
    g = EdgeGuard(EdgeParams(**kw), H)
    g.ticks = 0
    return g


def _step(g: EdgeGuard, z: float, r: float, approaching: bool, target: float = 1.0) -> int:
    """One tick of the guard at the next tick's time (target 1 mm)."""
    g.ticks += 1
    return g.update(g.ticks * H, z, r, approaching, target)


def test_fast_fall_is_held_then_closing_in_is_capped_and_judged():
    g = _guard()
    z, r = 5.0, 1.0
    assert _step(g, z, r, False) == OK
    g._verified(z - r)  # as an approach that judged the gain leaves it
    verdicts = []
    for _ in range(10):  # the reading widens at 100 mm/s with the axis still
        r += 100.0 * H
        verdicts.append(_step(g, z, r, False))
    assert FALLING in verdicts and g.probing
    assert g.down_cap_mm_s == EdgeParams().probe_mm_s
    for _ in range(40):  # the surface stops; the speed estimate decays
        v = _step(g, z, r, False)
    assert v == OK and g.probing
    for _ in range(40):  # closing in at 20 mm/s over a whole sheet: gain 1
        z -= 20.0 * H
        r -= 20.0 * H
        v = _step(g, z, r, False)
    assert v == OK and not g.probing and g.down_cap_mm_s == math.inf


def test_closing_in_after_a_fall_at_an_edge_is_an_edge():
    g = _guard()
    z, r = 5.0, 1.0
    _step(g, z, r, False)
    g._verified(z - r)
    for _ in range(10):
        r += 100.0 * H
        _step(g, z, r, False)
    for _ in range(40):
        _step(g, z, r, False)
    verdicts = []
    for _ in range(40):  # the reading shrinks 1.6x faster than the axis closes in
        z -= 20.0 * H
        r -= 1.6 * 20.0 * H
        verdicts.append(_step(g, z, r, False))
    assert EDGE in verdicts
    assert g.travel.gain == pytest.approx(1.6, rel=1e-6)


def test_approach_judges_the_gain_all_the_way():
    g = _guard()
    z, r = 10.0, 8.0
    verdicts = []
    for _ in range(200):
        z -= 30.0 * H
        r -= 1.5 * 30.0 * H
        verdicts.append(_step(g, z, r, True))
    assert verdicts[-1] == EDGE


def _s_curve(n_pre: int, n_move: int, n_after: int, v_mm_s: float, t1_s: float = 0.008):
    """Axis position (mm) for a velocity pulse through a first-order lag (the sim's axis)."""
    x = z = 0.0
    out = []
    for i in range(n_pre + n_move + n_after):
        u = v_mm_s if n_pre <= i < n_pre + n_move else 0.0
        x += (u - x) * H / t1_s
        z += x * H
        out.append(z)
    return np.asarray(out)


@pytest.mark.parametrize('k', [1.0, 1.3])
def test_fitted_gain_takes_a_quadratic_sheet_motion_out(k):
    rng = np.random.default_rng(1)
    z = 5.0 + _s_curve(50, 10, 50, 20.0) - 0.8 * np.arange(110) * H  # the axis follows too
    t = np.arange(z.size) * H
    sheet = 4.0 - 3.0 * t + 10.0 * t ** 2  # falling at 3 mm/s, decelerating
    r = k * (z - sheet) + 0.005 * rng.standard_normal(z.size)
    est, se, rms = edge.fitted_gain(list(t), list(z), list(r))
    assert rms == pytest.approx(0.005, rel=0.3)
    assert 0.02 < se < 0.08  # 5 µm noise over a ~100 µm move
    assert abs(est - k) < 3.0 * se
    # the trend alone would fool a travel ratio: over the window the reading moved far more
    # than k x the axis travel
    assert abs((r[-1] - r[0]) / (z[-1] - z[0]) - k) > 0.5
    # residuals that are not white (here a random walk, as band-limited gain noise) count as
    # fewer samples: the standard error exceeds the plain least-squares one
    walk = 0.001 * np.cumsum(rng.standard_normal(z.size))
    _, se_c, rms_c = edge.fitted_gain(list(t), list(z), list(k * (z - sheet) + walk))
    n = z.size
    tn = (t - t[0]) / (t[-1] - t[0])
    a = np.column_stack((z - z[0], np.ones(n), tn, tn ** 2, tn ** 3))
    plain = math.sqrt(rms_c ** 2 * n / (n - 5) * np.linalg.inv(a.T @ a)[0, 0])
    assert se_c > 2.0 * plain


class _Axis:
    """A guard in a loop: the verification's command moves the axis (integrator + lag)."""

    def __init__(self, guard: EdgeGuard, gain: float, sheet_mm_s: float = 0.0,
                 noise_mm: float = 0.005) -> None:
        self.g, self.k, self.vs, self.noise = guard, gain, sheet_mm_s, noise_mm
        self.z, self.x, self.t, self.u, self.sheet = 6.0, 0.0, 0.0, 0.0, 5.0
        self.rng = np.random.default_rng(2)

    def tick(self, target=1.0, approaching=False) -> int:
        self.x += (self.u - self.x) * H / 0.008
        self.z += self.x * H
        self.t += H
        self.sheet += self.vs * H
        r = self.k * (self.z - self.sheet) + self.noise * self.rng.standard_normal()
        v = self.g.update(self.t, self.z, r, approaching, target)
        self.u = self.g.verify_velocity_mm_s if v == VERIFY else 0.0
        return v


def _sunk(ax: _Axis, sink_mm: float) -> None:
    """Follow at rest, then let the apparent surface sink (the reading widens) until verified."""
    ax.tick()
    ax.g._verified(ax.g._z - ax.g._r)  # as an approach that judged the gain leaves it
    for _ in range(200):
        assert ax.tick() == OK
    ax.vs = -1.0 / ax.k  # the reading widens at 1 mm/s with the axis still
    n = 0
    while ax.tick() == OK:
        n += 1
    assert ax.g.verifying and ax.g._ticks == 1
    # it started once the sink passed verify_sink x target (the reading's 5 µm noise aside)
    assert n * H == pytest.approx(sink_mm, abs=0.03) or ax.noise > 0.005


def test_a_sink_below_the_verified_level_is_verified_by_a_move_up():
    p = EdgeParams()
    ax = _Axis(_guard(), 1.0)
    _sunk(ax, p.verify_sink * 1.0)
    z0 = ax.z
    verdicts = [VERIFY]
    while verdicts[-1] == VERIFY:
        verdicts.append(ax.tick())
    assert verdicts[-1] == OK  # over the sheet: verified
    assert len(verdicts) == round((p.verify_pre_s + p.verify_move_s + p.verify_settle_s) / H)
    assert 0.06 < ax.z - z0 < 0.12  # the move up (~100 µm), never down
    assert ax.g.gain == pytest.approx(1.0, abs=0.15)
    assert ax.g.verified_mm == pytest.approx(ax.sheet, abs=0.02)


def test_an_edge_gain_is_struck_twice_then_an_edge():
    ax = _Axis(_guard(), 1.4)
    _sunk(ax, 0.25)
    verdicts = [VERIFY]
    for _ in range(400):
        verdicts.append(ax.tick())
        if verdicts[-1] != VERIFY:
            break
    assert verdicts[-1] == EDGE
    p = EdgeParams()
    per = round((p.verify_pre_s + p.verify_move_s + p.verify_settle_s) / H)
    assert len(verdicts) == 2 * per  # verify_confirm = 2 in a row
    assert 'feedback gain 1.' in ax.g.reason and 'µm' in ax.g.reason


def test_a_verification_that_cannot_tell_holds(monkeypatch):
    # a fit above the limit by less than twice its standard error (a noisy sensor)
    monkeypatch.setattr(edge, 'fitted_gain', lambda t, z, r: (1.3, 0.2, 0.005))
    ax = _Axis(_guard(), 1.0)
    _sunk(ax, 0.25)
    v = VERIFY
    while v == VERIFY:
        v = ax.tick()
    assert v == HOLD and ax.g.doubts == 1
    p = EdgeParams()
    # held (nothing further down), then repeated after verify_retry_s: significant this time,
    # struck twice in a row, an edge
    monkeypatch.setattr(edge, 'fitted_gain', lambda t, z, r: (1.6, 0.1, 0.005))
    verdicts = [ax.tick() for _ in range(800)]
    first = verdicts.index(VERIFY)
    assert set(verdicts[:first]) == {HOLD}
    assert first * H == pytest.approx(p.verify_retry_s, abs=0.002)
    assert EDGE in verdicts


def test_a_verification_that_cannot_tell_is_repeated_only_so_often(monkeypatch):
    monkeypatch.setattr(edge, 'fitted_gain', lambda t, z, r: (1.3, 0.2, 0.005))
    ax = _Axis(_guard(), 1.0)
    _sunk(ax, 0.25)
    ax.vs = 0.0  # the surface stays where it sank
    verdicts = [ax.tick() for _ in range(2000)]
    p = EdgeParams()
    assert ax.g.doubts == 1 + p.verify_retries  # each one lifts the nozzle: a few, no more
    assert VERIFY not in verdicts[-1000:] and HOLD in verdicts[-1000:]


def test_a_fast_sink_holds_until_it_can_be_verified():
    ax = _Axis(_guard(), 1.0)
    ax.tick()
    ax.g._verified(ax.g._z - ax.g._r)
    for _ in range(200):
        ax.tick()
    ax.vs = -10.0  # 10 mm/s: faster than verify_speed_mm_s
    verdicts = [ax.tick() for _ in range(100)]
    assert HOLD in verdicts and VERIFY not in verdicts
    assert verdicts.index(HOLD) == pytest.approx(0.25 / (10.0 * H), abs=10)


def test_a_level_verified_stays_verified_for_the_memory():
    ax = _Axis(_guard(), 1.0)
    _sunk(ax, 0.25)
    while ax.tick() != OK:
        pass
    level = ax.g.verified_mm
    ax.vs = 1.0  # back up 0.4 mm, then down again to the verified level
    for _ in range(800):
        ax.tick()
    ax.vs = -1.0
    assert all(ax.tick() == OK for _ in range(700))  # within verify_memory_s: no move
    assert ax.sheet < level + 0.1 and ax.t < 1.0 + 0.5


def test_a_level_reached_without_a_judged_gain_is_verified_before_it_is_followed():
    ax = _Axis(_guard(), 1.4)  # an edge under a nozzle that arrived too slowly to judge it
    verdicts = [ax.tick() for _ in range(400)]
    assert verdicts[0] == OK and verdicts[1] == VERIFY  # at once, before any sink
    assert EDGE in verdicts
    ok = _Axis(_guard(), 1.0)
    verdicts = [ok.tick() for _ in range(400)]
    assert VERIFY in verdicts and EDGE not in verdicts and verdicts[-1] == OK
    assert math.isfinite(ok.g.verified_mm)


def test_a_follow_starting_close_to_its_target_verifies_first():
    g = _guard()
    g.reset(start_above_mm=0.5)
    assert g.verifying
    g.reset(start_above_mm=5.0)  # a long approach judges the gain on the way
    assert not g.verifying
    g.reset(start_above_mm=-0.5)  # moving up closes in on nothing (verified once followed)
    assert not g.verifying
    assert not EdgeGuard(EdgeParams(enabled=False), H).verifying


def test_probe_slower_than_the_judged_speed_is_rejected():
    p = ControllerParams(edge=EdgeParams(probe_mm_s=5.0, judge_mm_s=12.0))
    assert any('edge.probe_mm_s' in r for r in validate(p))
    assert not validate(ControllerParams(edge=EdgeParams(probe_mm_s=12.0, judge_mm_s=12.0)))


# ---------------------------------------------------------------- closed loop (sim models)

def _edge_run(cov: float, ramp_s: float, params: ControllerParams | None = None):
    sc = scenario_from_dict(dict(
        name='edge', duration_s=2.5, seed=3, initial_gap_mm=3.0,
        sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001},
        timeline=[{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                  {'t_s': 1.5, 'do': 'coverage', 'value': cov, 'ramp_s': ramp_s}]))
    c = FollowController(params or ControllerParams())
    return c, runner.run(sc, c, record_internals=True)


def _holds(res) -> list[str]:
    """Return the hold reasons of a run, each episode once, in order."""
    out: list[str] = []
    for r in res.internals['hold_reason']:
        if r and (not out or out[-1] != r):
            out.append(r)
    return out


def _never_down_after(res, first: str) -> None:
    """From the first hold whose reason starts with ``first`` on, no command toward the sheet."""
    reasons = list(res.internals['hold_reason'])
    k = next(i for i, r in enumerate(reasons) if r.startswith(first))
    assert np.all(np.asarray(res.command_mm_s)[k:] >= 0.0)


@pytest.mark.parametrize('cov', [0.06, 0.0])
def test_fast_slide_off_the_sheet_never_closes_in(cov):
    c, res = _edge_run(cov, 0.05)
    gap = np.asarray(res.true_gap_mm)
    if cov == 0.0:  # no reading at all: the sensor's miss-panel FAULT (no evidence to follow)
        assert c.fault_reason.startswith('miss-panel')
    else:  # held at the edge to the end, not latched (the sheet never comes back here)
        assert not c.fault_reason and res.internals['substate'][-1] == SubState.VOID_LOCK
        assert res.internals['hold_reason'][-1].startswith('edge')
        _never_down_after(res, 'edge')
    assert gap[int(1.5 / H):].min() >= 0.7  # 0.7 x the 1 mm target
    # and without the fall hold and the sink check it dives into the sheet (the test can fail)
    loose = params_from_dict({'edge': {'fall_mm_s': 10000.0, 'verify_sink': 0.0}})
    _, res2 = _edge_run(0.06, 0.05, loose)
    assert np.asarray(res2.true_gap_mm).min() < 0.3


def test_half_off_start_holds_on_the_approach():
    sc = load_scenario('edge_open_10_1')
    c = FollowController(ControllerParams())
    res = runner.run(sc, c, record_internals=True)
    holds = _holds(res)
    assert holds[0].startswith('edge: the nozzle is leaving the sheet')
    # held, its verifications (one per retry, the wait doubling) all find the edge
    assert all(h.startswith('edge: a move up of') for h in holds[1:]) and len(holds) <= 4
    assert not c.fault_reason and not c.followed
    assert np.asarray(res.true_gap_mm).min() > 1.0  # stopped far above the 1 mm target
    _never_down_after(res, 'edge')


@pytest.mark.parametrize('cov', [0.5, 0.06, 0.0])
def test_slow_slide_off_is_held_by_the_verification(cov):
    """A 1 s slide: the surface sinks slowly, a move up finds the gain, the nozzle holds."""
    c, res = _edge_run(cov, 1.0)
    gap = np.asarray(res.true_gap_mm)
    assert gap.min() >= 0.7  # the bar: 0.7 x the 1 mm target
    if cov == 0.0:
        assert c.fault_reason.startswith('miss-panel')  # the reading leaves the range at last
    else:
        assert not c.fault_reason
    assert any(h.startswith('edge: a move up of') for h in _holds(res))
    _never_down_after(res, 'edge')
    # without the verification the follow dives after the reading (the test can fail)
    _, off = _edge_run(cov, 1.0, params_from_dict({'edge': {'verify_sink': 0.0}}))
    assert np.asarray(off.true_gap_mm).min() < 0.55


def test_half_off_follow_starting_near_its_target_verifies_before_closing_in():
    sc = load_scenario('edge_step_2_5')  # starts 1.6 mm true at 2 mm target, half off
    c = FollowController(ControllerParams())
    res = runner.run(sc, c, record_internals=True)
    assert _holds(res)[0].startswith('edge: a move up of') and not c.fault_reason
    assert np.asarray(res.true_gap_mm).min() >= 1.6 - 0.01  # never closed in


def test_a_sheet_that_steps_down_is_followed_after_the_hold():
    sc = scenario_from_dict(dict(
        name='drop', duration_s=2.0, seed=3, initial_gap_mm=1.0,
        sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001},
        sheet={'profiles': [{'kind': 'step', 'size_mm': -0.5, 't_s': 1.0}]},
        timeline=[{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]))
    c = FollowController(ControllerParams())
    res = runner.run(sc, c, record_internals=True)
    assert c.counts['fall_hold'] > 0 and not c.fault_reason
    gap = np.asarray(res.true_gap_mm)
    assert abs(gap[-200:].mean() - 1.0) < 0.02


@pytest.mark.parametrize('cov', [0.3, 0.5])
def test_an_edge_hold_resumes_by_itself_once_back_over_the_sheet(cov):
    """The nozzle (1 - cov) off the sheet for 1.5 s: held, never closer, then following again.

    Before holds were released this was a latched FAULT (at 2.1-2.3 s) for the rest of the run.
    """
    sc = scenario_from_dict(dict(
        name='edge', duration_s=5.0, seed=3, initial_gap_mm=3.0,
        sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001},
        timeline=[{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                  {'t_s': 1.5, 'do': 'coverage', 'value': cov, 'ramp_s': 0.2},
                  {'t_s': 3.0, 'do': 'coverage', 'value': 1.0, 'ramp_s': 0.2}]))
    c = FollowController(ControllerParams())
    res = runner.run(sc, c, record_internals=True)
    assert not c.fault_reason
    reasons = list(res.internals['hold_reason'])
    held = np.flatnonzero([r.startswith('edge') for r in reasons])
    assert held.size and 1.5 < held[0] * H < 2.5
    gap = np.asarray(res.true_gap_mm)
    u = np.asarray(res.command_mm_s)
    assert np.all(u[held] >= 0.0)  # nothing toward the sheet while held
    assert gap.min() >= 0.7
    # released by itself within 0.5 s of the nozzle being back, then LADRC at the target
    assert 3.0 < held[-1] * H < 3.5
    st = np.asarray(res.internals['state'])
    after = int(4.0 / H)
    assert np.all(st[after:] == FollowState.LADRC) and not any(reasons[after:])
    assert abs(gap[-400:].mean() - 1.0) < 0.02


def test_a_held_edge_is_verified_again_with_a_doubling_wait(monkeypatch):
    """Held: one move up per retry, after hold_retry_s, 2x, 4x ...; a sheet found releases."""
    ax = _Axis(_guard(), 1.4)
    _sunk(ax, 0.25)
    v = VERIFY
    while v == VERIFY:
        v = ax.tick()
    assert v == EDGE and ax.g.held
    p = EdgeParams()
    verdicts = [ax.tick() for _ in range(int(2.0 / H))]
    starts = [i for i in range(1, len(verdicts))
              if verdicts[i] == VERIFY and verdicts[i - 1] != VERIFY]
    gaps_s = np.diff([0] + starts) * H
    assert gaps_s[:3] == pytest.approx([p.hold_retry_s * m for m in (1, 2, 4)], abs=0.002)
    assert set(verdicts) == {EDGE, VERIFY}  # never OK while the gain says edge
    # the nozzle comes back over the sheet at a new, lower level: the next retry finds gain 1
    ax.k = 1.0
    ax.vs = 0.0
    v = [ax.tick() for _ in range(int(4.5 / H))]
    assert OK in v and not ax.g.held
    assert ax.g.verified_mm == pytest.approx(ax.sheet, abs=0.02)


def test_a_held_edge_is_released_when_the_reading_narrows_back():
    ax = _Axis(_guard(), 1.4)
    _sunk_from = ax.sheet
    _sunk(ax, 0.25)
    level = ax.g.verified_mm
    v = VERIFY
    while v == VERIFY:
        v = ax.tick()
    assert v == EDGE
    for _ in range(100):
        assert ax.tick() == EDGE
    ax.k, ax.vs, ax.sheet = 1.0, 0.0, _sunk_from  # back over the same sheet
    assert ax.tick() == OK and not ax.g.held and ax.g.probing  # closing in is probed again
    assert ax.g.verified_mm == pytest.approx(level, abs=0.03)
