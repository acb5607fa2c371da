import numpy as np
import pytest
from scipy.optimize import brentq

from mpipe.acoustics.air import Air, air_properties
from mpipe.acoustics.bore import (
    Bore,
    Radiation,
    Segment,
    find_resonances,
    input_impedance,
    mean_flow_resistance,
    reflectance,
    transfer_matrix,
)
from mpipe.acoustics.ducts import propagation

# physics.md M: OpenWInD-RR dry air at 25 degC
AIR_M = Air(25.0, 1.184259, 346.2782, 1.844514e-5, 1.401848, 0.715657, "ernoult")
FREQS = np.arange(1.0, 1800.0, 0.05)


def peaks(bore, air=AIR_M, freqs=FREQS):
    z = input_impedance(bore, 2 * np.pi * freqs, air)
    return find_resonances(freqs, z, bore.entry_impedance(air))


def test_reference_cylinder_peaks():
    # physics.md M, cross-checked against OpenWInD 0.12.4
    bore = Bore((Segment(0.0, 0.5, radius=0.0075),))
    got = peaks(bore)
    np.testing.assert_allclose(
        [r.frequency_hz for r in got], [168.20, 508.20, 848.90, 1189.90, 1531.15], atol=0.03
    )
    np.testing.assert_allclose(
        [r.level_db for r in got], [31.640, 26.522, 23.826, 21.820, 20.156], atol=0.002
    )


def test_reference_cylinder_cone_cylinder_peaks():
    bore = Bore(
        (
            Segment(0.0, 0.03, radius=0.0065),
            Segment(0.03, 0.08, radius_start=0.0065, radius_end=0.0075),
            Segment(0.08, 0.58, radius=0.0075),
        )
    )
    got = peaks(bore)
    np.testing.assert_allclose(
        [r.frequency_hz for r in got], [148.55, 447.90, 744.90, 1037.95, 1327.50], atol=0.03
    )
    np.testing.assert_allclose(
        [r.level_db for r in got], [28.648, 24.267, 22.798, 22.119, 21.399], atol=0.002
    )


def test_lossless_closed_and_ideal_open_cylinders():
    air = air_properties(20.0)
    length = 0.6
    omega = 2 * np.pi * np.linspace(10.0, 3000.0, 3000)
    k = omega / air.c
    for model, expected in (
        ("ideal-open", lambda z0: 1j * z0 * np.tan(k * length)),
        ("closed", lambda z0: -1j * z0 / np.tan(k * length)),
    ):
        bore = Bore((Segment(0.0, length, radius=0.0075),), Radiation(model), "lossless")
        z0 = bore.entry_impedance(air)
        np.testing.assert_allclose(input_impedance(bore, omega, air), expected(z0), rtol=1e-7)
    # resonances of a lossy pipe with an ideal open end: where Im(Gamma) L = (2n - 1) pi / 2,
    # i.e. odd quarter wavelengths at the boundary-layer phase speed (slightly below c)
    bore = Bore((Segment(0.0, length, radius=0.0075),), Radiation("ideal-open"), "bessel")
    freqs = np.arange(20.0, 1000.0, 0.01)
    got = [r.frequency_hz for r in peaks(bore, air, freqs)][:3]
    for n, f in enumerate(got, start=1):
        want = brentq(
            lambda f, n=n: (
                propagation(np.array([2 * np.pi * f]), 0.0075, air)[0][0].imag * length
                - (2 * n - 1) * np.pi / 2
            ),
            10.0,
            2000.0,
        )
        assert f == pytest.approx(want, rel=2e-4)
        assert f < (2 * n - 1) * air.c / (4 * length)


def test_passive_input_impedance(shipped_calibration, shipped_air):
    omega = 2 * np.pi * np.linspace(1.0, 20000.0, 4000)
    for model in ("flanged", "unflanged", "flanged-norris"):
        bore = Bore(shipped_calibration.bore.segments, Radiation(model))
        assert np.all(input_impedance(bore, omega, shipped_air).real >= 0)
        assert np.all(np.abs(reflectance(bore, omega, shipped_air)) <= 1)


def test_transfer_matrix_of_part_of_bore(shipped_calibration, shipped_air):
    bore = shipped_calibration.bore
    omega = 2 * np.pi * np.linspace(20, 5000, 50)
    whole = transfer_matrix(bore, omega, shipped_air)
    split = transfer_matrix(bore, omega, shipped_air, 0.0, 0.2482) @ transfer_matrix(
        bore, omega, shipped_air, 0.2482, None
    )
    np.testing.assert_allclose(split, whole, rtol=1e-9, atol=1e-9 * np.abs(whole).max())
    same = transfer_matrix(bore, omega, shipped_air, 0.3, 0.3)
    np.testing.assert_allclose(same, np.broadcast_to(np.eye(2), same.shape))


def test_step_between_radii_is_transparent():
    # a step is the identity in the plane-wave approximation: splitting the bore at a step
    # gives the same matrix as the two halves chained
    air = air_properties(20.0)
    omega = 2 * np.pi * np.linspace(20, 5000, 50)
    stepped = Bore((Segment(0.0, 0.03, radius=0.0055), Segment(0.03, 0.5, radius=0.0075)))
    a = transfer_matrix(stepped, omega, air)
    b = transfer_matrix(Bore((Segment(0.0, 0.03, radius=0.0055),)), omega, air) @ transfer_matrix(
        Bore((Segment(0.0, 0.47, radius=0.0075),)), omega, air
    )
    np.testing.assert_allclose(a, b, rtol=1e-12)


def test_shipped_instrument_first_resonance_is_a_low_clarinet_note(
    shipped_calibration, shipped_air
):
    got = peaks(shipped_calibration.bore, shipped_air, np.arange(20.0, 1200.0, 0.1))
    assert len(got) >= 5
    # quarter-wave estimate with the flange end correction: c / 4(L + 0.82 a)
    estimate = shipped_air.c / (4 * (0.8182 + 0.8216 * 0.0075))
    assert got[0].frequency_hz == pytest.approx(estimate, rel=0.06)
    assert all(r.q > 10 for r in got)


@pytest.mark.parametrize("q_true", [10.0, 25.0, 60.0])
@pytest.mark.parametrize("df", [0.25, 0.5, 1.0, 2.0])
def test_q_is_that_of_an_analytic_single_resonance(q_true, df):
    # issue 33: `mpipe impedance` printed Q1 = 31.1 for a resonance whose Q is 25 (the band
    # read from the grid points inside it). Q is f / (half-power bandwidth), which a
    # single-degree-of-freedom resonance Z = R / (1 + jQ(f/f_r - f_r/f)) gives exactly;
    # within 1 % on grids down to a third of the bandwidth (2 Hz for Q = 60 at 150 Hz)
    from mpipe.acoustics.bore import find_resonances

    freqs = np.arange(20.0, 1000.0, df)
    z = 10.0 / (1 + 1j * q_true * (freqs / 150.0 - 150.0 / freqs))
    (r,) = find_resonances(freqs, z, 1.0, 1)
    assert r.frequency_hz == pytest.approx(150.0, rel=1e-4)
    assert r.level_db == pytest.approx(20.0, abs=0.01)
    assert r.q == pytest.approx(q_true, rel=0.01)


def test_half_power_bandwidth_of_a_curve_with_a_gap_is_nan_not_an_error():
    # a measured curve keeps NaN at the bins it could not measure (no coherence): a gap
    # inside the band leaves no parabola to fit, the bandwidth is unknown
    from mpipe.acoustics.bore import half_power_bandwidth

    freqs = np.linspace(90.0, 110.0, 41)
    level = -10 * np.log10(1 + ((freqs - 100.0) / 2.0) ** 2)  # Q = 25: -3 dB at +-2 Hz
    level[18] = np.nan
    assert np.isnan(half_power_bandwidth(freqs, level, 20, 0.0))
    level[18] = -10 * np.log10(1 + ((freqs[18] - 100.0) / 2.0) ** 2)
    assert half_power_bandwidth(freqs, level, 20, 0.0) == pytest.approx(4.0, rel=1e-6)


def test_mean_flow_resistance_is_poiseuilles_law_and_the_transfer_matrix_at_dc(
    shipped_calibration, shipped_air
):
    # a cylinder: 8 mu L / (pi a^4); a cone: the integral of 8 mu / (pi a(x)^4) by
    # quadrature (a second method); both the zero-frequency limit of the transfer matrix's
    # series term (the lossy ducts' own model, at 1 mHz)
    from scipy.integrate import quad

    air = shipped_air
    cylinder = Bore((Segment(0.0, 0.2, radius=0.0075),), Radiation())
    expected = 8 * air.mu * 0.2 / (np.pi * 0.0075**4)
    assert mean_flow_resistance(cylinder, air) == pytest.approx(expected, rel=1e-12)
    cone = Bore((Segment(0.0, 0.3, radius_start=0.007, radius_end=0.012),),
                Radiation())  # fmt: skip
    area = quad(lambda x: 8 * air.mu / (np.pi * (0.007 + 0.005 * x / 0.3) ** 4), 0.0, 0.3)[0]
    assert mean_flow_resistance(cone, air) == pytest.approx(area, rel=1e-9)
    omega = np.array([2 * np.pi * 1e-3])
    series = transfer_matrix(cylinder, omega, air)[0, 0, 1].real
    assert series == pytest.approx(expected, rel=1e-3)
    bore = shipped_calibration.bore
    part = mean_flow_resistance(bore, air, 0.0, shipped_calibration.reference_plane)
    series = transfer_matrix(bore, omega, air, 0.0, shipped_calibration.reference_plane)
    assert series[0, 0, 1].real == pytest.approx(part, rel=1e-2)  # observed 0.5 %
