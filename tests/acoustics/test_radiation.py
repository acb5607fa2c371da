import numpy as np
import pytest

from mpipe.acoustics.air import air_properties
from mpipe.acoustics.radiation import RADIATION_MODELS, radiation_impedance, reflection_coefficient

AIR = air_properties(20.0)
A = 0.0075
Z0 = AIR.impedance(np.pi * A**2)


@pytest.mark.parametrize(
    "model,end_correction,resistance",
    [
        ("unflanged", 0.6133, 0.25),  # Levine & Schwinger 1948
        ("flanged", 0.8216, 0.5),  # infinite flange
        ("flanged-norris", 0.8216, 0.5),
    ],
)
def test_low_frequency_limits(model, end_correction, resistance):
    ka = np.array([1e-3, 3e-3])
    z = radiation_impedance(ka * AIR.c / A, A, AIR, model) / Z0
    np.testing.assert_allclose(z.imag / ka, end_correction, rtol=1e-3)
    np.testing.assert_allclose(z.real / ka**2, resistance, rtol=2e-2)


def test_finite_flange_lies_between_unflanged_and_infinite():
    ka = np.array([0.01])
    omega = ka * AIR.c / A
    l_unfl = radiation_impedance(omega, A, AIR, "unflanged").imag
    l_inf = radiation_impedance(omega, A, AIR, "flanged").imag
    small = radiation_impedance(omega, A, AIR, "finite-flange", flange_radius=1.2 * A).imag
    large = radiation_impedance(omega, A, AIR, "finite-flange", flange_radius=20 * A).imag
    assert l_unfl < small < large < l_inf * 1.01
    assert abs(large / l_inf - 1) < 0.1


@pytest.mark.parametrize("model", [m for m in RADIATION_MODELS if m != "closed"])
def test_open_end_is_passive(model):
    omega = 2 * np.pi * np.linspace(1.0, 20000.0, 500)
    r = reflection_coefficient(omega, A, AIR, model, flange_radius=0.02)
    assert np.all(np.abs(r) <= 1 + 1e-12)
    z = radiation_impedance(omega, A, AIR, model, flange_radius=0.02)
    assert np.all(z.real >= -1e-12 * Z0)


def test_finite_flange_needs_its_radius():
    with pytest.raises(ValueError, match="flange_radius"):
        radiation_impedance(np.array([100.0]), A, AIR, "finite-flange")
