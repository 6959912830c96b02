"""Sheet profiles (frequency, amplitude, band limit) and the gas-pushed thin plate."""

import math

from ladrc_sim.models.axis import ParamError
from ladrc_sim.models.sheet import (
    Chirp,
    Plate,
    PlateParams,
    Ridge,
    Sheet,
    SheetParams,
    Sine,
    Square,
    Step,
    Triangle,
    Waviness,
)
import numpy as np
import pytest
from scipy import signal

H = 0.0005


def grid(duration_s):
    return np.arange(int(round(duration_s / H))) * H


def peak_hz(z):
    spec = np.abs(np.fft.rfft(z - z.mean()))
    return np.fft.rfftfreq(z.size, H)[np.argmax(spec)]


def rng():
    return np.random.default_rng(0)


def test_sine_frequency_amplitude_and_window():
    t = grid(10.0)
    z = Sine(amp_mm=0.4, freq_hz=3.0, t_start_s=1.0, t_end_s=9.0).evaluate(t, rng())
    assert peak_hz(z) == pytest.approx(3.0, abs=0.1)
    assert np.max(z) == pytest.approx(0.4, rel=1e-4)
    assert np.all(z[t < 1.0] == 0) and np.all(z[t >= 9.0] == 0)
    assert z[t >= 1.0][0] == 0.0  # starts at zero phase: no jump


def test_square_levels_and_zero_crossings():
    t = grid(4.0)
    z = Square(amp_mm=0.5, freq_hz=2.0).evaluate(t, rng())
    assert set(np.unique(z)) == {-0.5, 0.5}
    assert z[0] == 0.5
    assert np.count_nonzero(np.diff(np.sign(z))) == 2 * 2.0 * 4.0 - 1  # 2 edges per period


def test_triangle_amplitude_slope_and_frequency():
    t = grid(4.0)
    z = Triangle(amp_mm=0.5, freq_hz=1.5).evaluate(t, rng())
    assert np.max(z) == pytest.approx(0.5, abs=1e-3) and np.min(z) == pytest.approx(-0.5)
    assert np.max(np.abs(np.diff(z) / H)) == pytest.approx(4 * 0.5 * 1.5, rel=1e-6)
    assert peak_hz(z) == pytest.approx(1.5, abs=0.2)


def test_chirp_instantaneous_frequency_sweeps_0_to_5_hz():
    t = grid(12.0)
    z = Chirp(amp_mm=0.5, f0_hz=0.0, f1_hz=5.0, sweep_s=10.0, t_start_s=1.0).evaluate(t, rng())
    inside = (t >= 1.0) & (t < 11.0)
    assert np.all(z[~inside] == 0.0)
    # f(tau) = f1 tau / T  <=>  phase pi f1 tau^2 / T: zero crossings at tau_k = sqrt(k T / f1)
    zz = z[inside]
    cross = np.flatnonzero(np.sign(zz[1:]) != np.sign(zz[:-1])) + 1
    tau = t[inside][cross] - 1.0
    k = np.arange(1, tau.size + 1)
    np.testing.assert_allclose(tau, np.sqrt(k * 10.0 / 5.0), atol=H)
    assert tau.size == int(5.0 * 10.0 / 2.0 * 2) - 1  # 0..5 Hz over 10 s: 25 cycles
    assert np.max(np.abs(z)) == pytest.approx(0.5, rel=1e-3)


def test_waviness_rms_band_limit_and_seed():
    t = grid(20.0)
    w = Waviness(rms_mm=0.1, cutoff_hz=2.0)
    z = w.evaluate(t, np.random.default_rng(5))
    assert np.sqrt(np.mean(z * z)) == pytest.approx(0.1, rel=1e-9)
    f, p = signal.welch(z, fs=1 / H, nperseg=16384)
    assert p[f > 6.0].sum() < 1e-4 * p.sum()  # 8th-order (filtfilt) roll-off past 3x cutoff
    assert p[(f > 0.2) & (f < 1.5)].sum() > 0.5 * p.sum()
    np.testing.assert_array_equal(z, w.evaluate(t, np.random.default_rng(5)))
    assert not np.array_equal(z, w.evaluate(t, np.random.default_rng(6)))


def test_step_and_ridge():
    t = grid(3.0)
    assert np.all(Step(t_s=1.0, size_mm=0.7).evaluate(t, rng()) == np.where(t >= 1.0, 0.7, 0))
    r = Ridge(t_s=1.0, height_mm=0.2, width_s=0.1, gain_drop=0.3, period_s=1.0, count=2)
    z, g = r.evaluate(t, rng()), r.gain(t)
    for crest in (1.0, 2.0):
        i = int(round(crest / H))
        assert z[i] == pytest.approx(0.2) and g[i] == pytest.approx(0.7)
    far = np.abs(((t - 1.0 + 0.5) % 1.0) - 0.5) >= 0.05
    assert np.all(z[far] == 0.0) and np.all(g[far] == 1.0)


def test_sheet_sums_profiles_and_collects_ridge_gain():
    prof = (Step(t_s=0.5, size_mm=1.0), Sine(amp_mm=0.2, freq_hz=1.0),
            Ridge(t_s=0.25, height_mm=0.1, width_s=0.1, gain_drop=0.5))
    sh = Sheet(SheetParams(prof), 2000, H)
    t = sh.t_s
    expect = sum(p.evaluate(t, rng()) for p in prof)
    np.testing.assert_allclose(sh.base_mm, expect)
    assert sh.feedback_gain.min() == pytest.approx(0.5)
    assert sh.height_mm(1500) == pytest.approx(expect[1500])
    with pytest.raises(ParamError, match='plate'):
        SheetParams((PlateParams(), PlateParams()))


def test_plate_free_vibration_has_the_parameterised_frequency_and_damping():
    fn, zeta = 8.0, 0.05
    plate = Plate(PlateParams(natural_freq_hz=fn, damping_ratio=zeta, gas_k_mm2_s2=0.0,
                              kick_t_s=0.0, kick_velocity_mm_s=30.0), H)
    y = np.array([plate.step(1.0) for _ in range(4000)])
    up = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    fd = 1.0 / np.mean(np.diff(up) * H)
    assert fd == pytest.approx(fn * math.sqrt(1 - zeta * zeta), rel=0.01)
    peaks = signal.find_peaks(y)[0]
    delta = np.mean(np.log(y[peaks[:-1]] / y[peaks[1:]]))
    assert delta == pytest.approx(2 * math.pi * zeta / math.sqrt(1 - zeta * zeta), rel=0.02)
    # kicked with v0 from rest: first peak ~ v0 / w
    assert y[peaks[0]] == pytest.approx(30.0 / (2 * math.pi * fn), rel=0.1)


def test_gas_push_falls_with_the_gap_and_sets_the_static_deflection():
    p = PlateParams(natural_freq_hz=5.0, damping_ratio=0.5, gas_k_mm2_s2=1000.0, gas_g0_mm=0.5)
    plate = Plate(p, H)
    pushes = [plate.push_mm_s2(g) for g in (0.0, 0.5, 1.0, 2.0, 5.0)]
    assert np.all(np.diff(pushes) < 0)
    assert pushes[0] == pytest.approx(1000.0 / 0.5)
    assert plate.push_mm_s2(-1.0) == pushes[0]  # clamped at contact
    for _ in range(8000):  # held gap of 1 mm: equilibrium y = -a / w^2
        plate.step(1.0)
    w = 2 * math.pi * 5.0
    assert plate.y_mm == pytest.approx(-(1000.0 / 1.5) / w ** 2, rel=1e-3)
    plate.set_gas(False)
    for _ in range(8000):
        plate.step(1.0)
    assert abs(plate.y_mm) < 1e-3


def test_profile_parameters_are_checked():
    with pytest.raises(ValueError, match='freq_hz'):
        Sine(freq_hz=-1.0)
    with pytest.raises(ValueError, match='t_end_s'):
        Sine(t_start_s=2.0, t_end_s=1.0)
    with pytest.raises(ValueError, match='damping_ratio'):
        PlateParams(damping_ratio=1.5)


@pytest.mark.parametrize('seed', range(5))
def test_waviness_has_no_start_up_transient(seed):
    # A low cutoff (long filter memory) must not leave a jump at the start of the run: the
    # first 0.2 s stay within the band of the rest (a 2 mm step here once sent the approach up).
    t = np.arange(0.0, 25.0, 0.0005)
    z = Waviness(rms_mm=0.15, cutoff_hz=1.5).evaluate(t, np.random.default_rng(seed))
    assert np.sqrt(np.mean(z * z)) == pytest.approx(0.15, rel=1e-9)
    assert np.abs(z[:400]).max() < 4 * 0.15
    assert np.abs(np.diff(z[:400])).max() / 0.0005 < 10.0  # mm/s: no fast start-up motion
