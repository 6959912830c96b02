"""The excitation signal and its player: bounds, return to start, safety."""

import math

from ladrc_tools.commissioning.excitation import H_S, Excitation
from ladrc_tools.commissioning.player import ExcitationPlayer, PlayerLimits
from ladrc_tools.commissioning.simrun import apply_overrides, run_excitation, scenario_dict
import numpy as np
import pytest

CASES = [
    Excitation(),
    Excitation(kind='chirp'),
    # a long random walk in a narrow band: without the travel bound it would leave it
    Excitation(kind='prbs', amplitude_mm_s=20.0, max_travel_mm=0.05, f_low_hz=0.5,
               f_high_hz=1000.0, duration_s=60.0, seed=3),
    Excitation(kind='prbs', amplitude_mm_s=1.0, max_travel_mm=0.2, f_low_hz=2.0,
               f_high_hz=20.0, duration_s=9.0, seed=11),
    Excitation(kind='chirp', amplitude_mm_s=20.0, max_travel_mm=2.0, f_low_hz=0.2,
               f_high_hz=1000.0, duration_s=10.0),
    Excitation(kind='chirp', amplitude_mm_s=0.5, max_travel_mm=0.01, f_low_hz=5.0,
               f_high_hz=50.0, duration_s=0.5),
]


@pytest.mark.parametrize('exc', CASES, ids=lambda e: f'{e.kind}-{e.amplitude_mm_s:g}-'
                         f'{e.max_travel_mm:g}-{e.duration_s:g}s')
def test_profile_stays_in_its_bounds_and_returns_to_start(exc):
    assert exc.problems() == []
    u = exc.velocity_mm_s()
    p = exc.position_mm()
    assert u.size == round(exc.duration_s / H_S)
    assert u[0] == 0.0 and u[-1] == 0.0
    assert np.all(np.isfinite(u))
    assert np.max(np.abs(u)) <= exc.amplitude_mm_s * (1 + 1e-12)
    assert np.max(np.abs(p)) <= exc.max_travel_mm * (1 + 1e-9)
    assert abs(p[-1]) < 1e-9 * exc.max_travel_mm
    # it does move: most of the travel and a real share of the amplitude are used
    assert np.max(np.abs(p)) > 0.3 * exc.max_travel_mm
    assert np.sqrt(np.mean(u ** 2)) > 0.3 * exc.amplitude_mm_s
    # the same seed gives the same profile
    assert np.array_equal(u, exc.velocity_mm_s())


def test_prbs_is_binary_on_its_clock_and_random_per_seed():
    exc = Excitation(duration_s=10.0, f_high_hz=100.0, f_low_hz=1.0)
    u = exc.velocity_mm_s()
    moving = u[u != 0.0]
    # ±amplitude except the one partial tick that lands the return on the start
    assert np.mean(np.abs(np.abs(moving) - exc.amplitude_mm_s) < 1e-12) > 0.999
    clock = exc.clock_ticks()
    assert clock == 10  # 1/(2·100 Hz) = 5 ms
    flips = np.flatnonzero(np.diff(np.sign(u)) != 0)
    runs = np.diff(flips)
    # runs are whole clocks except where the travel bound turned the sign early
    assert np.mean(runs % clock == 0) > 0.5
    assert runs.max() <= round(1 / (2 * exc.f_low_hz * H_S)) + clock
    other = Excitation(duration_s=10.0, seed=1).velocity_mm_s()
    assert not np.array_equal(u, other)


def test_chirp_sweeps_from_f_low_to_f_high():
    exc = Excitation(kind='chirp', f_low_hz=2.0, f_high_hz=100.0, duration_s=4.0)
    u = exc.velocity_mm_s()
    n = u.size
    early = u[n // 10:n // 5]
    late = u[-n // 5:-n // 10]

    def crossings_hz(x):
        return np.count_nonzero(np.diff(np.sign(x)) != 0) / (2 * x.size * H_S)

    f_early, f_late = crossings_hz(early), crossings_hz(late)
    # log sweep: 2 Hz · 50^(t/T); 10-20 % of the run ≈ 3-4 Hz, 80-90 % ≈ 45-68 Hz
    assert 2.5 < f_early < 5.0
    assert 35.0 < f_late < 80.0


@pytest.mark.parametrize('field, value, word', [
    ('kind', 'sine', 'kind'),
    ('amplitude_mm_s', 25.0, 'amplitude_mm_s'),
    ('amplitude_mm_s', 0.0, 'amplitude_mm_s'),
    ('amplitude_mm_s', math.nan, 'finite'),
    ('max_travel_mm', 3.0, 'max_travel_mm'),
    ('max_travel_mm', math.inf, 'finite'),
    ('f_high_hz', 1500.0, 'Nyquist'),
    ('f_low_hz', 200.0, 'f_low < f_high'),
    ('f_low_hz', 0.1, 'one period'),
    ('duration_s', 0.2, 'duration_s'),
    ('duration_s', 61.0, 'duration_s'),
    ('seed', -1, 'seed'),
    ('amplitude_mm_s', True, 'finite'),
])
def test_bad_excitations_are_refused_with_their_reason(field, value, word):
    exc = Excitation(**{field: value})
    reasons = exc.problems()
    assert reasons and any(word in r for r in reasons), reasons
    with pytest.raises(ValueError, match='excitation'):
        exc.velocity_mm_s()


def test_return_must_fit_in_the_run():
    reasons = Excitation(amplitude_mm_s=0.5, max_travel_mm=2.0, duration_s=4.0).problems()
    assert any('quarter' in r for r in reasons)


def _play(sets, exc=None, limits=None):
    data = apply_overrides(scenario_dict(None), sets)
    return run_excitation(data, exc or Excitation(duration_s=1.0), limits)


def test_player_plays_the_profile_after_the_settle_time():
    exc = Excitation(duration_s=1.0)
    played = _play([], exc, PlayerLimits(settle_s=0.1))
    res, pl = played.result, played.player
    assert pl.finished and pl.abort_reason == ''
    k0 = pl.start_tick
    assert np.all(res.command_mm_s[:k0] == 0.0)
    assert np.array_equal(res.command_mm_s[k0:k0 + exc.velocity_mm_s().size],
                          exc.velocity_mm_s())
    assert np.all(res.command_mm_s[k0 + exc.velocity_mm_s().size:] == 0.0)
    enc = res.encoder_mm
    # b0 = 1, T1 = 8 ms: inside the profile's bound plus T1·A, back at the start
    assert np.max(np.abs(enc - enc[0])) <= exc.max_travel_mm + 0.008 * exc.amplitude_mm_s
    assert abs(enc[-1] - enc[0]) <= 0.002
    assert np.all(res.internals['command_enable'] == 1.0)


def test_player_aborts_on_a_runaway_axis():
    # a drive with three times the expected gain leaves travel + margin: abort, zero after
    played = _play(['axis.b0=3.0'], Excitation(duration_s=2.0))
    pl, res = played.player, played.result
    assert 'beyond' in pl.abort_reason and not pl.finished
    en = res.internals['command_enable']
    k = int(np.argmin(en))
    assert en[k] == 0.0 and np.all(en[k:] == 0.0)
    assert np.all(res.command_mm_s[k:] == 0.0)
    assert pl.max_excursion_mm <= pl.bound_mm + 3.0 * 4.7 * 0.0005 * 2


def test_player_refuses_to_move_near_the_sheet():
    played = _play(['initial_gap_mm=0.8'])
    assert 'below min_gap_mm' in played.player.abort_reason
    assert np.all(played.result.command_mm_s == 0.0)


def test_player_stops_when_the_drive_faults():
    data = apply_overrides(scenario_dict(None), [])
    data['timeline'] = [{'t_s': 0.5, 'do': 'drive', 'enabled': True, 'fault': True}]
    played = run_excitation(data, Excitation(duration_s=1.0))
    assert 'faulted' in played.player.abort_reason
    res = played.result
    assert np.all(res.command_mm_s[int(0.5 / H_S):] == 0.0)


def test_player_limits_are_checked():
    with pytest.raises(ValueError, match='settle_s'):
        ExcitationPlayer(Excitation(), PlayerLimits(settle_s=-1.0))
