"""Measured impedance files: declared layouts, the known traps, comparison with theory."""

import math

import numpy as np
import pytest

from mpipe.cli.main import main
from mpipe.core.errors import UserError
from mpipe.measurement.impedance import impedance_curve
from mpipe.measurement.impedance_comparison import compare
from mpipe.measurement.measured_impedance import (
    ImpedanceFileLayout,
    phase_direction,
    read_measured_impedance,
    write_impedance_file,
)
from tests.conftest import SHIPPED


@pytest.fixture(scope="module")
def theory(shipped_calibration):
    return impedance_curve(shipped_calibration, 20.0, 2500.0, 0.5)


def _openwind(path, freqs, z):
    # OpenWInD's write_impedance layout: "%e %e %e" per line, no header
    path.write_text(
        "".join(f"{f:e} {v.real:e} {v.imag:e}\n" for f, v in zip(freqs, z, strict=True))
    )
    return path


def test_openwind_file_needs_its_normalisation_declared(tmp_path, theory):
    path = _openwind(tmp_path / "z.txt", theory.freqs_hz, theory.z / theory.z0)
    with pytest.raises(UserError, match=r"normalisation is not declared .* looks like Z/Zc"):
        read_measured_impedance(path)
    m = read_measured_impedance(path, {"normalisation": "Z/Zc"})
    np.testing.assert_allclose(m.z, theory.z / theory.z0, rtol=1e-6)
    result = compare(m.freqs, m.z, theory.freqs_hz, theory.z / theory.z0)
    assert np.all(np.abs(result.table["error_cents"]) < 0.1)
    assert np.all(np.abs(result.table["error_db"]) < 0.01) and result.band_error_db < 1e-3


def test_a_warmer_measurement_shows_its_resonances_sharp_by_the_sound_speed_ratio(
    tmp_path, shipped_calibration, theory
):
    warm = impedance_curve(shipped_calibration, 20.0, 2500.0, 0.5, temperature_c=25.0)
    path = _openwind(tmp_path / "warm.txt", warm.freqs_hz, warm.z / warm.z0)
    m = read_measured_impedance(path, {"normalisation": "Z/Zc"})
    result = compare(m.freqs, m.z, theory.freqs_hz, theory.z / theory.z0)
    c20 = shipped_calibration.air_properties(20.0).c
    c25 = shipped_calibration.air_properties(25.0).c
    expected = 1200 * math.log2(c25 / c20)  # resonance frequencies scale with c
    assert len(result.table) >= 5
    np.testing.assert_allclose(result.table["error_cents"], expected, atol=1.0)


def test_header_row_csv_with_absolute_impedance(tmp_path, theory):
    # pympedance-style: a header row naming the columns, Z in Pa s/m^3 (SI acoustic ohm)
    path = tmp_path / "z.csv"
    rows = [
        f"{f:.6f},{v.real:.9e},{v.imag:.9e}" for f, v in zip(theory.freqs_hz, theory.z, strict=True)
    ]
    path.write_text("f (Hz),Re Z (Pa s/m^3),Im Z (Pa s/m^3)\n" + "\n".join(rows) + "\n")
    m = read_measured_impedance(path)
    assert m.layout.normalisation == "Pa s/m^3"
    np.testing.assert_allclose(m.normalised(theory.z0), theory.z / theory.z0, rtol=1e-6)


def test_magnitude_and_phase_columns_need_their_unit(tmp_path, theory):
    z = theory.z / theory.z0
    body = "\n".join(
        f"{f},{abs(v)},{math.degrees(np.angle(v))}" for f, v in zip(theory.freqs_hz, z, strict=True)
    )
    (tmp_path / "a.csv").write_text("freq,mag,phase\n" + body)
    with pytest.raises(UserError, match="column 'phase'.*degrees or radians"):
        read_measured_impedance(tmp_path / "a.csv", {"normalisation": "Z/Zc"})
    (tmp_path / "b.csv").write_text("freq,mag,phase_deg\n" + body)
    m = read_measured_impedance(tmp_path / "b.csv", {"normalisation": "Z/Zc"})
    np.testing.assert_allclose(m.z, z, rtol=1e-9)


def test_stored_minus_im_is_caught_and_read_when_declared(tmp_path, theory):
    z = theory.z / theory.z0
    assert phase_direction(theory.freqs_hz, z) < 0  # e^{+jwt}: the phase falls at a peak
    path = _openwind(tmp_path / "conj.txt", theory.freqs_hz, np.conj(z))
    with pytest.raises(UserError, match="phase rises through the impedance peaks"):
        read_measured_impedance(path, {"normalisation": "Z/Zc"})
    m = read_measured_impedance(path, {"normalisation": "Z/Zc", "time_convention": "-jwt"})
    np.testing.assert_allclose(m.z, z, rtol=1e-6)
    m = read_measured_impedance(
        path, {"normalisation": "Z/Zc", "columns": ["frequency_hz", "re", "minus_im"]}
    )
    np.testing.assert_allclose(m.z, z, rtol=1e-6)


def test_negative_real_part_is_refused(tmp_path, theory):
    z = theory.z / theory.z0
    path = _openwind(tmp_path / "neg.txt", theory.freqs_hz, -z)
    with pytest.raises(UserError, match="passive impedance has Re Z >= 0"):
        read_measured_impedance(path, {"normalisation": "Z/Zc"})


def test_own_format_round_trips_with_header_and_sidecar(tmp_path, theory):
    z = theory.z / theory.z0
    layout = ImpedanceFileLayout(
        columns=("frequency_hz", "re", "im"), normalisation="Z/Zc", time_convention="-jwt",
        temperature_c=21.5,
    )  # fmt: skip
    path = write_impedance_file(tmp_path / "own.txt", theory.freqs_hz, z, layout)
    m = read_measured_impedance(path)
    assert m.layout.temperature_c == 21.5
    np.testing.assert_allclose(m.z, z, rtol=1e-8)
    side = _openwind(tmp_path / "side.txt", theory.freqs_hz, z * theory.z0)
    (tmp_path / "side.yaml").write_text("normalisation: Pa s/m^3\n")
    assert read_measured_impedance(side).layout.normalisation == "Pa s/m^3"
    (tmp_path / "side.yaml").write_text("normalisation: Z/Zc\ncolumns: [frequency_hz, re]\n")
    with pytest.raises(UserError, match="side.yaml|columns"):
        read_measured_impedance(side)


def test_impedance_command_compares_measured_theory_and_take(tmp_path, theory, capsys):
    z = theory.z / theory.z0
    path = _openwind(tmp_path / "z.txt", theory.freqs_hz, z)
    take = tmp_path / "impedance.csv"
    rng = np.random.default_rng(0)
    noisy = z * (1 + 0.01 * rng.standard_normal(z.size))
    take.write_text("frequency_hz,z_measured_re,z_measured_im\n" + "\n".join(
        f"{f},{v.real},{v.imag}" for f, v in zip(theory.freqs_hz, noisy, strict=True)))  # fmt: skip
    args = ["impedance", str(SHIPPED), "--measured", str(path), "--normalisation", "Z/Zc",
            "--fmax", "2000", "--take-impedance", str(take), "--plot", str(tmp_path / "c.png"),
            "--csv", str(tmp_path / "c.csv")]  # fmt: skip
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "measured against theory: band error 0.00 dB" in out
    assert "take's own impedance against the measured file" in out
    assert (tmp_path / "c.png").stat().st_size > 1000
    assert "error_cents" in (tmp_path / "c.csv").read_text()
    # undeclared normalisation: one line, naming the file, exit 2
    assert main(["impedance", str(SHIPPED), "--measured", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "z.txt: the normalisation is not declared" in err


def test_a_measured_table_given_as_calibration_gets_a_hint(tmp_path, theory, capsys):
    path = _openwind(tmp_path / "z.txt", theory.freqs_hz[:50], theory.z[:50] / theory.z0)
    assert main(["impedance", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "not a calibration file" in err and "--measured" in err and "\n" not in err
