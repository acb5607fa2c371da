import pytest

from mpipe.acoustics.air import air_properties, temperature_from_sound_speed

# physics.md A, table of values computed from the two formula sets (dry air)
KEEFE = {
    20: (343.28, 1.2039, 1.8144e-5, 0.7092),
    25: (346.16, 1.1842, 1.8375e-5, 0.7078),
    30: (349.05, 1.1645, 1.8605e-5, 0.7064),
}
ERNOULT = {
    20: (343.36, 1.2045, 1.8206e-5, 0.7165),
    25: (346.28, 1.1843, 1.8445e-5, 0.7157),
    30: (349.17, 1.1647, 1.8684e-5, 0.7149),
}


@pytest.mark.parametrize("model,table", [("keefe", KEEFE), ("ernoult", ERNOULT)])
@pytest.mark.parametrize("t", [20, 25, 30])
def test_tabulated_values(model, table, t):
    air = air_properties(t, model)
    c, rho, mu, pr = table[t]
    assert air.c == pytest.approx(c, abs=0.01)
    assert air.rho == pytest.approx(rho, abs=1e-4)
    assert air.mu == pytest.approx(mu, rel=1e-3)
    assert air.prandtl == pytest.approx(pr, abs=1e-4)


def test_breath_like_air_ernoult():
    # physics.md A.2: 32 degC, RH 100 %, 4 % CO2 gives c ~ 349.3 m/s and gamma ~ 1.392
    air = air_properties(32.0, "ernoult", humidity=1.0, co2_fraction=0.04)
    assert air.c == pytest.approx(349.3, abs=0.2)
    assert air.gamma == pytest.approx(1.392, abs=0.001)


def test_temperature_inverts_sound_speed():
    for t in (15.0, 20.0, 33.3):
        assert temperature_from_sound_speed(air_properties(t).c) == pytest.approx(t, abs=1e-9)


def test_implausible_temperature_is_rejected():
    with pytest.raises(ValueError, match="degrees Celsius"):
        air_properties(293.15)


def test_unknown_model_is_rejected():
    with pytest.raises(ValueError, match="unknown air model"):
        air_properties(20.0, "ideal")


def test_temperature_inverts_the_ernoult_sound_speed():
    # the calibration's own model: the Keefe inverse would read a perfect c ~0.2-0.6 degC off
    for t, h, co2 in ((12.0, 0.0, 4.2e-4), (20.0, 0.5, 4.2e-4), (31.0, 1.0, 0.03)):
        c = air_properties(t, "ernoult", humidity=h, co2_fraction=co2).c
        back = temperature_from_sound_speed(c, "ernoult", humidity=h, co2_fraction=co2)
        assert back == pytest.approx(t, abs=1e-9)
    c20 = air_properties(20.0, "ernoult").c
    assert abs(temperature_from_sound_speed(c20) - 20.0) > 0.1  # the models do differ
