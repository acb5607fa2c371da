"""Comparing impedance curves: peaks of |Z| on any grid, resonances matched in cents."""

import math

import numpy as np

from mpipe.measurement.impedance_comparison import compare, plot_comparison, resonances


def _modes(freqs, modes=((150.0, 30.0), (450.0, 25.0))):
    """Sum of resonances z = A / (1 + j Q (f / f_r - f_r / f)), Z/Zc (dimensionless)."""
    return sum(20.0 / (1.0 + 1j * q * (freqs / f_r - f_r / freqs)) for f_r, q in modes)


def test_resonances_on_a_non_uniform_grid():
    freqs = np.geomspace(50.0, 1000.0, 4000)
    peaks = resonances(freqs, _modes(freqs), 1.0)
    assert list(peaks.columns) == ["frequency_hz", "level_db", "bandwidth_hz"]
    np.testing.assert_allclose(peaks.frequency_hz, [150.0, 450.0], rtol=2e-3)
    # a single-mode peak's half-power bandwidth is f_r / Q (issue 33: within 1 %, not 10 %)
    np.testing.assert_allclose(peaks.bandwidth_hz, [150.0 / 30.0, 450.0 / 25.0], rtol=0.01)
    assert peaks.level_db[0] > 25.0


def test_identical_curves_match_and_a_far_peak_does_not():
    freqs = np.arange(20.0, 2000.0, 0.5)
    z = _modes(freqs)
    same = compare(freqs, z, freqs, z)
    assert len(same.table) == 2 and same.band_hz == (50.0, 2000.0)
    np.testing.assert_allclose(same.table.error_cents, 0.0, atol=1e-9)
    assert same.band_error_db == 0.0
    # a second resonance 100 cents away is beyond match_cents = 50
    far = compare(freqs, _modes(freqs, ((150.0, 30.0), (450.0 * 2 ** (1 / 12), 25.0))), freqs, z)
    # (the first moves a little with its neighbour)
    assert abs(far.table.error_cents[0]) < 1.0 and math.isnan(far.table.error_cents[1])


def test_plot_comparison_writes_a_png(tmp_path):
    freqs = np.arange(20.0, 2000.0, 1.0)
    plot_comparison(tmp_path / "z.png", [("theory", freqs, _modes(freqs))], (50.0, 2000.0))
    assert (tmp_path / "z.png").stat().st_size > 1000


def test_a_measured_curve_prints_the_q_of_its_resonance():
    # the Q `mpipe impedance` prints for a measured curve (its peaks found on any grid)
    # is that of an analytic resonance Z/Zc = 10 / (1 + 25j (f/150 - 150/f)), on a 2 Hz grid
    from mpipe.measurement.impedance import ImpedanceCurve, format_resonances

    freqs = np.arange(20.0, 1000.0, 2.0)
    z = 10.0 / (1 + 25j * (freqs / 150.0 - 150.0 / freqs))
    curve = ImpedanceCurve(freqs, z, 1.0, 20.0, "measured", measured=True)
    (r,) = curve.resonances(1)
    assert abs(r.q - 25.0) < 0.25
    assert format_resonances([r]).splitlines()[1].split()[-1] == "25.0"
