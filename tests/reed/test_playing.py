"""Playing frequency of a known periodic signal."""

import math

import numpy as np
import pytest

from mpipe.reed.playing import playing_frequency


def test_playing_frequency_of_a_known_signal():
    fs = 100_000.0
    t = np.arange(20_000) / fs
    # a band-limited square-ish wave: odd harmonics up to 5.6 kHz
    x = sum(np.sin(2 * np.pi * k * 147.3 * t + k) / k for k in range(1, 40, 2))
    assert playing_frequency(x, fs) == pytest.approx(147.3, rel=1e-6)
    assert playing_frequency(x[:5000], fs) == pytest.approx(147.3, rel=1e-5)
    assert math.isnan(playing_frequency(np.zeros(1000), fs))
