"""Encoder quantization and injected glitches."""

import math

from ladrc_sim.models.encoder import Encoder, EncoderParams, Glitch
import pytest

H = 0.0005


def test_quantized_to_the_resolution():
    e = Encoder(EncoderParams(resolution_mm=0.001), 10)
    assert e.read(0, 1.23456) == pytest.approx(1.235, abs=1e-12)
    assert e.read(1, -0.0004) == pytest.approx(0.0, abs=1e-12)
    assert Encoder(EncoderParams(resolution_mm=0.0), 1).read(0, 1.23456) == 1.23456


def test_jump_and_stuck_glitches_at_their_times():
    g = (Glitch('jump', t_s=2 * H, duration_s=2 * H, size_mm=0.5),
         Glitch('stuck', t_s=6 * H, duration_s=3 * H))
    e = Encoder(EncoderParams(resolution_mm=0.0), 12, H, g)
    r = [e.read(i, float(i)) for i in range(12)]
    assert r == [0, 1, 2.5, 3.5, 4, 5, 5, 5, 5, 9, 10, 11]
    e = Encoder(EncoderParams(resolution_mm=0.0), 5, H, (Glitch('jump', 0.0, math.inf, 1.0),))
    assert [e.read(i, 0.0) for i in range(5)] == [1.0] * 5


def test_bad_glitch_kind():
    with pytest.raises(ValueError, match='kind'):
        Glitch('flip')
