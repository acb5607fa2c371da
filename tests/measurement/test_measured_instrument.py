"""A measured input impedance as the instrument (bore.measured).

The measurement is made from the theory's own impedance of the shipped bore, band-limited
to 50-4000 Hz with 1 % complex noise: the measured bore must give the geometry's reflection
function and, on a take played by the geometry, the geometry's inversion within the SEs.
"""

import numpy as np
import pytest
import yaml

from mpipe.acoustics.bore import input_impedance
from mpipe.acoustics.reflection import reflection_function
from mpipe.core.config import ConfigError
from mpipe.inversion.preparation.kernel import bore_kernel
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.whole_take.take import invert_take
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.measured_impedance import ImpedanceFileLayout, write_impedance_file
from mpipe.measurement.measured_instrument import bore_description
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters
from tests.conftest import SHIPPED

FS = 100_000.0
BAND = (50.0, 4000.0)
NOISE = 0.01


def _measured_calibration(folder, seed=1, normalisation="Z/Zc", temperature_c=20.0):
    cal = load_calibration(SHIPPED)
    air = cal.air_properties(temperature_c)
    z0 = cal.bore.entry_impedance(air)
    f = np.arange(BAND[0], BAND[1] + 0.5, 1.0)
    z = input_impedance(cal.bore, 2 * np.pi * f, air)
    rng = np.random.default_rng(seed)
    z = z * (1 + NOISE * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) / 2**0.5)
    if normalisation == "Z/Zc":
        z = z / z0
    layout = ImpedanceFileLayout(
        columns=("frequency_hz", "re", "im"),
        normalisation=normalisation,
        temperature_c=temperature_c,
    )
    write_impedance_file(folder / "z.txt", f, z, layout)
    data = yaml.safe_load(SHIPPED.read_text())
    data["bore"]["measured"] = "z.txt"
    path = folder / "measured.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    return load_calibration(_measured_calibration(tmp_path_factory.mktemp("measured")))


def test_the_equivalent_bore_and_its_stated_error(measured):
    m = measured.bore.measured_input
    assert m.band_hz == BAND and m.temperature_c == 20.0
    # the geometry made the data: the fit finds its length, the misfit is the noise's
    assert m.equivalent_length == pytest.approx(measured.bore.length, abs=2e-4)
    assert m.misfit_rms_db < 0.15 and m.misfit_cents < 3.0
    assert "the bore is measured" in bore_description(measured)


@pytest.mark.parametrize("temperature_c", [20.0, 24.0])
def test_the_measured_bore_gives_the_geometrys_reflection_function(measured, temperature_c):
    geometry = load_calibration(SHIPPED)
    air = geometry.air_properties(temperature_c)
    rf_g = reflection_function(geometry.bore, air, FS)
    rf_m = reflection_function(measured.bore, air, FS)
    assert rf_m.n_taps == rf_g.n_taps
    rel = np.linalg.norm(rf_m.h - rf_g.h) / np.linalg.norm(rf_g.h)
    # 1 % noise in 50-4000 Hz; the temperature moves the measured curve by the sound speed
    # only (its losses stay as measured): a few 1e-3 of the response
    assert rel < (0.004 if temperature_c == 20.0 else 0.008), rel
    omega = 2 * np.pi * np.linspace(1.0, 50_000.0, 20_000)
    assert np.all(input_impedance(measured.bore, omega, air).real >= 0)


def test_absolute_and_normalised_files_agree(tmp_path, measured):
    absolute = load_calibration(_measured_calibration(tmp_path, normalisation="Pa s/m^3"))
    a, b = absolute.bore.measured_input, measured.bore.measured_input
    assert np.allclose(a.z_norm, b.z_norm, rtol=1e-8)


def test_a_measured_bore_is_one_fingering(tmp_path):
    path = _measured_calibration(tmp_path)
    data = yaml.safe_load(path.read_text())
    data["bore"]["holes"] = [{"name": "h1", "position": 0.5, "radius": 0.003, "chimney": 0.003}]
    data["fingerings"] = {"x": [], "o": ["h1"]}
    data["fingering"] = "x"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="a measured impedance is one fingering"):
        load_calibration(path)
    data.pop("fingerings"), data.pop("fingering")
    data["bore"]["measured"] = "missing.txt"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="bore.measured: no such impedance file"):
        load_calibration(path)


def test_the_measured_bore_inverts_a_take_like_the_geometry(measured):
    geometry = load_calibration(SHIPPED)
    truth = ReedParameters(
        k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
    )
    kernel, _ = bore_kernel(geometry, FS, 20.0)
    sim = simulate(truth, kernel, 34000)
    rng = np.random.default_rng(3)  # 40 dB SNR on p and u, about what the front end gives
    p = sim.p + 1e-2 * np.std(sim.p) * rng.standard_normal(sim.p.size)
    u = sim.u + 1e-2 * np.std(sim.u) * rng.standard_normal(sim.u.size)
    config = InversionConfig(estimator="window")  # at the calibration's temperature
    tables = [
        invert_take(
            p, u, FS, cal, config, ExecutorConfig(workers=1), windows=[26000, 30000]
        ).tracking.table
        for cal in (geometry, measured)
    ]
    assert all((t["status"] == "ok").all() for t in tables)
    for name in ("k", "S", "y_m", "p_m", "lam"):
        g, m = (np.median(t[name]) for t in tables)
        se = np.hypot(*(np.median(t[f"{name}_se"]) for t in tables))
        assert abs(m - g) <= 2 * se, (name, m / g - 1, se / g)


def test_the_impedance_table_of_a_measured_bore_has_no_noise_peaks(measured):
    from mpipe.measurement.impedance import impedance_curve

    theory = impedance_curve(load_calibration(SHIPPED), 20.0, 2000.0, 0.5).resonances(6)
    noisy = impedance_curve(measured, 20.0, 2000.0, 0.5).resonances(6)
    assert len(noisy) == len(theory) == 6
    for a, b in zip(noisy, theory, strict=True):
        assert abs(1200 * np.log2(a.frequency_hz / b.frequency_hz)) < 5.0


def test_mpipes_own_impedance_export_round_trips_as_a_measurement(tmp_path, capsys):
    # `mpipe impedance --csv` (frequency_hz, z_real, z_imag, zc in Pa s/m^3) read back: as a
    # file to compare (no difference to theory) and as a measured bore (its equivalent bore
    # is the geometry's own length, resonances within a cent)
    from mpipe.cli.main import main

    export = tmp_path / "z.csv"
    assert main(["impedance", str(SHIPPED), "--fmin", "40", "--fmax", "3000", "--df", "1",
                 "--csv", str(export)]) == 0  # fmt: skip
    assert main(["impedance", str(SHIPPED), "--measured", str(export), "--fmax", "3000"]) == 0
    out = capsys.readouterr().out
    assert "read as Pa s/m^3" in out and "band error 0.00 dB" in out
    data = yaml.safe_load(SHIPPED.read_text())
    data["bore"]["measured"] = "z.csv"
    for mic in data.get("microphones", []):
        mic.pop("calibration", None)  # the shipped tables are beside the shipped file
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(data))
    cal = load_calibration(tmp_path / "m.yaml")
    m = cal.bore.measured_input
    assert m.equivalent_length == pytest.approx(cal.bore.length, abs=2e-4)
    assert m.misfit_cents < 1.0 and m.misfit_rms_db < 0.1
    line = bore_description(cal)
    assert "the bore is measured" in line and "dB rms" in line and "cents" in line
