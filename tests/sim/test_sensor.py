"""Capacitive sensor model: ideal reading, edge gain (notes §5.3 item 3), range, flags."""

import math

from ladrc_sim.models.sensor import Sensor, SensorParams, edge_reading_mm, oscillator_hz
import numpy as np
import pytest
from scipy.optimize import brentq

H = 0.0005


def ideal(**kw):
    return Sensor(SensorParams(**kw), 1000, H, np.random.default_rng(0))


def test_full_coverage_ideal_sensor_reads_the_true_gap():
    s = ideal()
    for i, g in enumerate([0.01, 0.5, 1.0, 3.3, 12.0, 19.99]):
        assert s.measure(i, g, 1.0) == (g, True, False)


def test_edge_gain_is_above_one_and_moves_a_2_to_5_step_about_2_16_mm():
    s = ideal(edge_ripple=0.0)
    g = np.linspace(0.05, 15, 300)
    r = np.array([s.apparent_gap_mm(x, 0.5) for x in g])
    assert np.all(r > g)
    slope = np.diff(r) / np.diff(g)
    assert np.all(slope > 1.0) and np.all(np.diff(slope) < 0)  # gain > 1, growing as gap closes
    # slope at contact tends to 1/c (analytic limit of the model)
    d = 1e-6
    assert (s.apparent_gap_mm(d, 0.5) - s.apparent_gap_mm(0.0, 0.5)) / d == pytest.approx(2.0,
                                                                                         rel=1e-3)
    # notes §5.3: commanded 2 -> 5 mm at the edge, the encoder moved 2.16 mm
    ga = brentq(lambda x: s.apparent_gap_mm(x, 0.5) - 2.0, 0.0, 20.0)
    gb = brentq(lambda x: s.apparent_gap_mm(x, 0.5) - 5.0, 0.0, 20.0)
    assert gb - ga == pytest.approx(2.16, abs=0.05)


def test_feedback_ratio_d1_d0_falls_unevenly_when_closing_at_the_edge():
    s = ideal(edge_ripple=0.1)
    g = np.linspace(10.0, 1.0, 19)  # 0.5 mm steps from 10 mm down to 1 mm
    r = np.array([s.apparent_gap_mm(x, 0.5) for x in g])
    ratio = np.diff(g) / np.diff(r)  # true travel d1 over read travel d0, per step
    assert np.all(ratio < 1.0) and np.all(ratio > 0.0)
    assert ratio[-1] < ratio[0] - 0.15  # falls as the gap closes
    smooth = np.diff(g) / np.diff(edge_reading_mm(g, 0.5))
    assert np.max(np.abs(ratio - smooth)) > 0.005  # uneven (ripple), yet monotonic map
    fine = np.linspace(0, 19, 5000)
    assert np.all(np.diff([s.apparent_gap_mm(x, 0.3) for x in fine]) > 0)


def test_off_the_sheet_and_out_of_range_are_invalid_and_saturated():
    s = ideal()
    assert s.measure(0, 1.0, 0.0) == (20.0, False, False)  # miss-panel
    assert s.measure(1, 25.0, 1.0) == (20.0, False, False)
    reading, valid, collision = s.measure(2, -0.2, 1.0)
    assert (reading, valid, collision) == (0.0, False, True)
    assert s.measure(3, 0.0, 1.0)[2] is True  # contact counts as collision
    assert s.measure(4, 1e-6, 1.0)[2] is False


def test_gain_schedule_multiplies_the_reading():
    gain = np.full(10, 0.7)
    s = Sensor(SensorParams(), 10, H, np.random.default_rng(0), gain_schedule=gain)
    assert s.measure(0, 2.0, 1.0)[0] == pytest.approx(1.4)


def test_first_order_lag_step_response():
    tau = 0.002
    s = ideal(lag_s=tau)
    s.measure(0, 1.0, 1.0)
    y = [s.measure(k, 2.0, 1.0)[0] for k in range(1, 41)]
    k = np.arange(1, 41)
    np.testing.assert_allclose(y, 2.0 - np.exp(-k * H / tau), atol=1e-12)


def test_quantization_and_noise_statistics():
    s = Sensor(SensorParams(quant_mm=0.01), 10, H)
    r = s.measure(0, 1.23456, 1.0)[0]
    assert r == pytest.approx(1.23, abs=1e-12)
    n = 20000
    s = Sensor(SensorParams(noise_std_mm=0.02), n, H, np.random.default_rng(1))
    x = np.array([s.measure(i, 5.0, 1.0)[0] for i in range(n)])
    assert np.std(x) == pytest.approx(0.02, rel=0.05)
    assert np.mean(x) == pytest.approx(5.0, abs=0.001)


def test_gain_noise_has_the_requested_spread():
    n = 20000
    s = Sensor(SensorParams(gain_noise_std=0.05, gain_noise_cutoff_hz=50.0), n, H,
               np.random.default_rng(2))
    assert np.std(s.gain) == pytest.approx(0.05, rel=0.02)


def test_oscillator_frequency_falls_as_the_nozzle_approaches():
    p = SensorParams()
    f = oscillator_hz(np.array([0.5, 1.0, 5.0, 20.0]), p)
    assert np.all(np.diff(f) > 0)
    area = math.pi * 16.0
    c_s = 8.8541878128e-3 * area / 1.0
    assert f[1] == pytest.approx(500e3 / math.sqrt(1 + c_s / 10.0))


def test_bad_parameters_are_rejected():
    with pytest.raises(ValueError, match='range_max_mm'):
        SensorParams(range_min_mm=5.0, range_max_mm=2.0)
    with pytest.raises(ValueError, match='edge_ripple'):
        SensorParams(edge_ripple=1.5)
